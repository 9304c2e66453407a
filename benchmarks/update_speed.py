"""The learner's updates alone, on one collected rollout: PPO's (and, for MAAIP, the
discriminators'), with `benchmarks/train_speed.py`'s settings for each objective.

One rollout of the default 64 arenas x 32 steps is collected, then `Trainer.update_policy`
(and `MotionPriors.update_discriminators`) run `REPEATS` times on it, both cores. An update's
time does not depend on the physics, so this is the steadier measure of what
`train_speed.py`'s "ppo" and "discriminators" columns cost; the figures are per environment
step of the rollout, median and best of the repeats. ``--profile`` adds torch.profiler's
table of one PPO update (the operators by their own time).
Prints, last, ``ppo_update: U us/env step`` (the median).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

# As `ringside` sets it (flows/cli/environment.py).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch  # noqa: E402

from models.humanoid.boxer import BoneLengths  # noqa: E402
from models.maaip.config import OBJECTIVES  # noqa: E402
from models.maaip.trainer import Trainer  # noqa: E402
from storage.assets import pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.train.config import TrainConfig  # noqa: E402
from tasks.train.data import clip_demonstrations  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import tracker_gate  # noqa: E402  (beside this file)

REPEATS = 8


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--objective", choices=OBJECTIVES, default="track", help="what the trainer learns"
    )
    parser.add_argument("--profile", action="store_true", help="torch.profiler's table too")
    args = parser.parse_args()
    assets = data_paths().assets
    pull(assets, dev=True, log=lambda _line: None)
    config = TrainConfig()
    data = clip_demonstrations(assets, "punch")
    if args.objective == "track":
        gate = tracker_gate.parser().parse_args(["--threads", str(config.env.threads)])
        config = tracker_gate.tracking_config(gate)
        data = tracker_gate.synthetic_adversary(assets, BoneLengths(), float(config.env.policy_hz))
    trainer = Trainer(config, data)
    try:
        torch.set_num_threads(1)
        rollout = trainer.collect()
        torch.set_num_threads(config.env.threads)
        learned = trainer.objective.learn(rollout, 0, lambda _name, fn, *a: fn(*a))
        reward = learned.rewards["total"]
        steps = rollout.terminated.numel()
        timings: dict[str, list[float]] = {"ppo": [], "discriminators": []}
        discriminators = getattr(trainer.objective, "update_discriminators", None)
        for _ in range(REPEATS):
            if discriminators is not None:
                inputs = trainer.objective.discriminator_inputs(rollout)
                start = time.perf_counter()
                discriminators(inputs)
                timings["discriminators"].append(time.perf_counter() - start)
            start = time.perf_counter()
            trainer.update_policy(rollout, reward)
            timings["ppo"].append(time.perf_counter() - start)
        if args.profile:
            from torch.profiler import ProfilerActivity, profile

            with profile(activities=[ProfilerActivity.CPU]) as prof:
                trainer.update_policy(rollout, reward)
            print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=20))
    finally:
        trainer.close()
    print(
        f"objective {config.objective}: {steps} env steps per rollout, {config.ppo.epochs} epochs "
        f"of minibatches of {config.ppo.minibatch_size}, {config.network.hidden_sizes}, "
        f"{config.env.threads} threads, {REPEATS} repeats"
    )
    for name, times in timings.items():
        if times:
            print(
                f"{name}: median {statistics.median(times) / steps * 1e6:.0f} us/env step, "
                f"best {min(times) / steps * 1e6:.0f}"
            )
    print(f"ppo_update: {statistics.median(timings['ppo']) / steps * 1e6:.0f} us/env step")


if __name__ == "__main__":
    main()
