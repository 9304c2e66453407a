"""Settings for tiny training runs and evaluations (seconds, not minutes): the tests' and the
benchmarks' (which import this file directly; it has no side effects, unlike conftest)."""

# `ringside train` flags for a run of tiny networks and batches (seconds, not minutes).
TINY_TRAIN_FLAGS = [
    "--train-network-hidden",
    "16,16",
    "--train-env-num-envs",
    "4",
    "--train-ppo-horizon",
    "4",
    "--train-ppo-minibatch-size",
    "16",
    "--train-ppo-epochs",
    "1",
    "--train-discriminator-samples-per-update",
    "16",
    "--train-discriminator-updates-per-iteration",
    "1",
]
# `ringside evaluate` flags for a few short bouts and a one-second video.
TINY_EVALUATE_FLAGS = [
    "--evaluate-episodes",
    "4",
    "--evaluate-episode-frames",
    "60",
    "--evaluate-video-seconds",
    "1",
]
