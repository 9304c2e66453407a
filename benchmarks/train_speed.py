"""Training throughput against raw physics, in one run, with the default `cpu` preset.

``--objective maaip`` (the default): the demonstrations are DeepMimic's punch clip performed by
two facing fighters (`facing_reference`), so the benchmark needs no processed footage.
``--objective track``: the tracker on the synthetic adversary's seven clips with
`benchmarks/tracker_gate.py`'s settings (its defaults, both cores). Measured, best of 3 each:
- raw physics: `ArenaEnv.step_physics` with zero actions (N environments x the default
  substeps of both fighters, no observations, no learning);
- end to end: `Trainer.iterate` (policy inference, environment steps with observations,
  rewards, discriminator and PPO updates), environment steps per second of wall time, with
  the split of an iteration's time; "other collection" is the collection's time beyond the raw
  physics (observations, contacts, references and, for the tracker, its rewards).
Prints both and, last, ``train_vs_physics: R x`` (end to end over raw physics).

``--stepping warp`` steps the arenas on MuJoCo Warp (`models.arena.stepping.warp`), on the GPU
with ``--device cuda``, and measures the default stepping's raw physics in the same run beside
it; ``--envs`` sets the batch (1,024 to 8,192 worlds suit a GPU).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

# As `ringside` sets it (flows/cli/environment.py).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from models.arena.config import STEPPINGS, EnvConfig  # noqa: E402
from models.arena.env import ArenaEnv  # noqa: E402
from models.humanoid.boxer import BoneLengths  # noqa: E402
from models.maaip.config import OBJECTIVES  # noqa: E402
from models.maaip.trainer import Trainer  # noqa: E402
from storage.assets import pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.train.config import TrainConfig  # noqa: E402
from tasks.train.data import clip_demonstrations  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import tracker_gate  # noqa: E402  (beside this file)

REPEATS = 3
PHYSICS_STEPS = 100


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--envs",
        type=int,
        help="environments per batch instead of the default (the PPO minibatch scales with it)",
    )
    parser.add_argument(
        "--stepping",
        "--backend",
        choices=STEPPINGS,
        help="how the arenas are stepped (train.env.stepping) instead of the default",
    )
    parser.add_argument(
        "--device", default="cpu", help="where the networks (and Warp's worlds) run: cpu or cuda"
    )
    parser.add_argument(
        "--objective", choices=OBJECTIVES, default="maaip", help="what the trainer learns"
    )
    parser.add_argument("--epochs", type=int, help="PPO epochs instead of the default")
    parser.add_argument(
        "--minibatches", type=int, help="PPO minibatches per epoch instead of the default"
    )
    args = parser.parse_args()
    assets = data_paths().assets
    pull(assets, dev=True, log=lambda _line: None)
    demos = clip_demonstrations(assets, "punch")
    config = TrainConfig()
    data = demos
    if args.objective == "track":
        gate = tracker_gate.parser().parse_args(["--threads", str(config.env.threads)])
        config = tracker_gate.tracking_config(gate)
        data = tracker_gate.synthetic_adversary(assets, BoneLengths(), float(config.env.policy_hz))
    if args.envs:
        # The same number of minibatches per epoch as the defaults.
        scale = args.envs / config.env.num_envs
        config = dataclasses.replace(
            config,
            env=dataclasses.replace(config.env, num_envs=args.envs),
            ppo=dataclasses.replace(
                config.ppo, minibatch_size=round(config.ppo.minibatch_size * scale)
            ),
        )
    if args.epochs or args.minibatches:
        ppo = config.ppo
        batch = 2 * ppo.horizon * config.env.num_envs  # both agents' samples
        config = dataclasses.replace(
            config,
            ppo=dataclasses.replace(
                ppo,
                epochs=args.epochs or ppo.epochs,
                minibatch_size=batch // args.minibatches
                if args.minibatches
                else ppo.minibatch_size,
            ),
        )
    default = config.env
    config = dataclasses.replace(config, device=args.device)
    if args.stepping:
        config = dataclasses.replace(
            config, env=dataclasses.replace(config.env, stepping=args.stepping)
        )
    n = config.env.num_envs
    physics = raw_physics(config.env, demos, args.device)
    baseline = None
    if config.env.stepping != default.stepping:
        env = dataclasses.replace(config.env, stepping=default.stepping)
        baseline = raw_physics(env, demos, "cpu")

    trainer = Trainer(config, data)
    try:
        trainer.iterate()  # warm-up: first calls allocate
        best, split = 0.0, {}
        for _ in range(REPEATS):
            start = time.perf_counter()
            metrics = trainer.iterate()
            rate = config.ppo.horizon * n / (time.perf_counter() - start)
            if rate > best:
                best = rate
                split = {
                    k: metrics[k]
                    for k in ("collect_s", "rewards_s", "discriminators_s", "ppo_s")
                    if k in metrics
                }
    finally:
        trainer.close()
    total = sum(split.values())
    print(
        f"objective {config.objective}: environments {n}, horizon {config.ppo.horizon}, "
        f"{config.ppo.epochs} epochs of minibatches of {config.ppo.minibatch_size}, preset "
        f"{config.network.preset} {config.network.hidden_sizes}, stepping {config.env.stepping}, "
        f"{config.env.threads} threads"
    )
    print(f"raw_physics: {physics:,.0f} env steps/s")
    if baseline is not None:
        print(
            f"raw_physics with stepping {default.stepping} (the default), same run: "
            f"{baseline:,.0f} env steps/s ({physics / baseline:.3f} x)"
        )
    print(f"end_to_end: {best:,.0f} env steps/s")
    print("split: " + ", ".join(f"{k[:-2]} {v / total:.0%}" for k, v in split.items()))
    # Microseconds of wall time per environment step: the ratio can reach 0.5 only if everything
    # besides the physics (which already uses every core) fits in the physics' own time.
    steps = config.ppo.horizon * n
    per_step = ", ".join(f"{k[:-2]} {v / steps * 1e6:.0f}" for k, v in split.items())
    other = split["collect_s"] / steps * 1e6 - 1e6 / physics
    print(
        f"per env step (us): raw physics {1e6 / physics:.0f}; end to end: {per_step} "
        f"(collect = raw physics + other collection {other:.0f})"
    )
    print(f"train_vs_physics: {best / physics:.3f} x")


def raw_physics(config: EnvConfig, demos, device: str) -> float:
    """Environment steps per second of `ArenaEnv.step_physics`, best of `REPEATS`: batches of
    `PHYSICS_STEPS` steps of 64 environments' worth (fewer steps of a larger batch)."""
    n = config.num_envs
    steps = max(1, PHYSICS_STEPS * 64 // n)
    with ArenaEnv(config, np.random.default_rng(0), demos.bones, device) as env:
        env.reset(np.arange(n), demos.reference)
        env.step_physics()  # warm-up: Warp loads its kernels on the first step
        best = 0.0
        for _ in range(REPEATS):
            start = time.perf_counter()
            for _ in range(steps):
                env.step_physics()
            best = max(best, steps * n / (time.perf_counter() - start))
    return best


if __name__ == "__main__":
    main()
