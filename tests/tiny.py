"""Settings for tiny training runs and evaluations (seconds, not minutes): the tests' and the
benchmarks' (which import this file directly; it has no side effects, unlike conftest)."""

# A run of tiny networks and batches.
TINY_TRAIN = {
    "train.network.hidden": "16,16",
    "train.env.num_envs": "4",
    "train.ppo.horizon": "4",
    "train.ppo.minibatch_size": "16",
    "train.ppo.epochs": "1",
    "train.discriminator.samples_per_update": "16",
    "train.discriminator.updates_per_iteration": "1",
}
# A few short bouts and a one-second video.
TINY_EVALUATE = {
    "evaluate.episodes": "4",
    "evaluate.episode_frames": "60",
    "evaluate.video_seconds": "1",
}
# The whole pipeline to the opponent in seconds: two iterations of the tiny run, evaluated.
TINY_PIPELINE = {**TINY_TRAIN, "train.iterations": "2", **TINY_EVALUATE}


def flags(settings: dict[str, str]) -> list[str]:
    """``settings`` as `ringside` flags (``--SECTION-NAME VALUE``)."""
    return [
        part
        for name, value in settings.items()
        for part in ("--" + name.replace(".", "-").replace("_", "-"), value)
    ]


def toml(settings: dict[str, str]) -> str:
    """``settings`` as a ringside.toml (values as text, as flags give them)."""
    tables: dict[str, list[str]] = {}
    for name, value in settings.items():
        table, _, leaf = name.rpartition(".")
        tables.setdefault(table, []).append(f'{leaf} = "{value}"')
    return "".join(f"[{t}]\n" + "\n".join(lines) + "\n" for t, lines in tables.items())


TINY_TRAIN_FLAGS = flags(TINY_TRAIN)
TINY_EVALUATE_FLAGS = flags(TINY_EVALUATE)
TINY_PIPELINE_FLAGS = flags(TINY_PIPELINE)
