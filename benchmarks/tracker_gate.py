"""The tracker gate (issues 32, 49): train trackers on the synthetic adversary from a fresh start,
gate them now and then, and say when each held its gate.

The synthetic adversary's clips: DeepMimic's walk and punch and the walker's forward walk and
four turns (`tasks.deepmimic`), retargeted onto `BoneLengths()`, tracked by both fighters of
every arena (`models.tracking`). The trainer is the project's own (`Trainer` with
objective 'track'); this script adds the tracking PPO settings below, a checkpoint every
``--checkpoint-every`` iterations in FOLDER/seed-K (``checkpoint.pt``, and ``progress.json``
with the training seconds and the gate figures so far), and `track_gate` every
``--gate-every``: every clip from its first frame, both agents, acting on the policy's mean.
Stopped (Ctrl-C, a kill, ``--minutes``) and started again on the same FOLDER it resumes from
the checkpoints, as the train stage does, and its clocks go on from the seconds saved there
(training alone, and wall time with the gates).

Gate (`TrackConfig`'s gate settings): >= 90 % of clips finished, mean body error <= 5 cm, root
error <= 10 cm. It is *held* when met in at least 3 of the last 5 checks (`gate_held`). Each
seed's run ends when the gate is held (unless ``--keep-going``), at ``--iterations`` or after
``--minutes`` of wall time (the gates' time counted); ``progress.json`` keeps the first check
that met it and the one that held it. Each gate prints one line; the last line is the median
over ``--seeds`` of the wall-clock minutes to the held gate (``inf`` when fewer than half held
it): ``tracker_gate_held_minutes: M min``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

# As `ringside` sets it (flows/cli/environment.py).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch  # noqa: E402

from models.arena.config import STEPPINGS  # noqa: E402
from models.humanoid.boxer import BoneLengths  # noqa: E402
from models.maaip.trainer import Trainer  # noqa: E402
from models.tracking.clips import TrackingData, tracking_data  # noqa: E402
from models.tracking.gate import gate_held, gate_met, track_gate  # noqa: E402
from storage.assets import pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.deepmimic import WALKER_CLIPS, clip_path, load_deepmimic, retarget  # noqa: E402
from tasks.train.config import TrainConfig  # noqa: E402

CLIPS = ("walk", "punch", *WALKER_CLIPS)
# Where `make bench` keeps the runs (benchmarks/warp_replay.py replays seed 0's tracker).
DEFAULT_FOLDER = Path("data/bench/tracker_gate")


def synthetic_adversary(assets: Path, bones: BoneLengths, fps: float) -> TrackingData:
    """The seven clips on ``bones``, for both agents."""
    clips = {
        name: retarget(load_deepmimic(clip_path(assets, name)), bones, fps=fps) for name in CLIPS
    }
    return tracking_data((clips, clips), (bones, bones), fps=fps, key="synthetic-adversary")


# The tracker's defaults (`OBJECTIVE_DEFAULTS`), which this benchmark's own defaults are.
TRACKER = TrainConfig(objective="track").with_preset()


def tracking_config(args: argparse.Namespace, seed: int = 0) -> TrainConfig:
    """The tracker's defaults with this benchmark's arguments, for ``seed``."""
    base = TRACKER
    return TrainConfig(
        objective="track",
        seed=seed,
        device=args.device,
        iterations=args.iterations,
        track=dataclasses.replace(
            base.track,
            value_sees_partner=args.value_sees_partner,
            hard_start_share=args.hard_start_share,
        ),
        ppo=dataclasses.replace(
            base.ppo,
            epochs=args.epochs,
            learning_rate=args.learning_rate,
            action_std=args.action_std,
            gamma=args.gamma,
            # ``--minibatches`` per epoch of both agents' samples, whatever the arenas.
            minibatch_size=2 * base.ppo.horizon * args.envs // args.minibatches,
        ),
        env=dataclasses.replace(
            base.env, num_envs=args.envs, threads=args.threads, stepping=args.stepping
        ),
    )


def _write(path: Path, data: bytes) -> None:
    """Replace ``path`` atomically, so a kill mid-write leaves the previous one."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_bytes(data)
    tmp.replace(path)


def parser() -> argparse.ArgumentParser:
    """This benchmark's arguments (benchmarks/warp_replay.py reads its defaults too)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "folder",
        type=Path,
        nargs="?",
        default=DEFAULT_FOLDER,
        help=f"checkpoints and progress, resumed if present (default {DEFAULT_FOLDER})",
    )
    parser.add_argument(
        "--minutes", type=float, default=20.0, help="each seed's wall-clock budget (all sessions)"
    )
    parser.add_argument("--iterations", type=int, default=100_000, help="at most this many")
    parser.add_argument("--checkpoint-every", type=int, default=20)
    parser.add_argument("--gate-every", type=int, default=20)
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument(
        "--threads", type=int, default=TRACKER.env.threads, help="cores (physics and torch)"
    )
    parser.add_argument("--stepping", choices=STEPPINGS, default=TRACKER.env.stepping)
    parser.add_argument("--device", default="cpu", help="cpu or cuda (networks and Warp)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--learning-rate", type=float, default=TRACKER.ppo.learning_rate)
    parser.add_argument(
        "--action-std", type=float, default=TRACKER.ppo.action_std, help="every action's std"
    )
    parser.add_argument("--gamma", type=float, default=TRACKER.ppo.gamma, help="DeepMimic's 0.95")
    parser.add_argument(
        "--epochs",
        type=int,
        default=3,
        help="PPO epochs: 3 on these clips with hard starts (docs/train.md, 'Time to the gate'); "
        f"the stage's default is {TRACKER.ppo.epochs}",
    )
    parser.add_argument(
        "--minibatches",
        type=int,
        # 4: the default minibatch (1,024) of the default batch (64 arenas x 32 steps x 2 agents).
        default=2 * TRACKER.ppo.horizon * TRACKER.env.num_envs // TRACKER.ppo.minibatch_size,
        help="PPO minibatches per epoch",
    )
    parser.add_argument(
        "--hard-start-share",
        type=float,
        default=0.5,
        help="train.track.hard_start_share: 0.5 on these clean clips, 0 the stage's default",
    )
    parser.add_argument(
        "--value-sees-partner",
        action="store_true",
        help="the value reads the other agent's observation too (MAAIP's centralised value)",
    )
    parser.add_argument(
        "--keep-going", action="store_true", help="train on after the gate is met (the curve)"
    )
    return parser


def main() -> None:
    args = parser().parse_args()
    torch.set_num_threads(args.threads)
    assets = data_paths().assets
    pull(assets, dev=True, log=lambda _line: None)
    held = {}
    for seed in args.seeds:
        print(f"seed {seed}:", flush=True)
        held[seed] = run_seed(args, seed, assets)
    times = [held[s] if held[s] is not None else math.inf for s in args.seeds]
    print(
        "held at: "
        + ", ".join(
            f"seed {s} "
            + (f"{t:.1f} min" if math.isfinite(t) else f"not within {args.minutes:g} min")
            for s, t in zip(args.seeds, times, strict=True)
        )
    )
    print(f"tracker_gate_held_minutes: {statistics.median(times):.1f} min")


def run_seed(args: argparse.Namespace, seed: int, assets: Path) -> float | None:
    """Train (or resume) seed ``seed``'s tracker in FOLDER/seed-K until its gate is held or its
    budget is spent; the wall-clock minutes at the check that held it, or None."""
    config = tracking_config(args, seed)
    track = config.track
    data = synthetic_adversary(assets, BoneLengths(), float(config.env.policy_hz))
    folder = args.folder / f"seed-{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    checkpoint, progress_file = folder / "checkpoint.pt", folder / "progress.json"
    trainer = Trainer(config, data)
    progress: dict = {"train_s": 0.0, "wall_s": 0.0, "gates": []}
    if checkpoint.exists():
        trainer.restore(checkpoint.read_bytes())
        progress = json.loads(progress_file.read_text())
        print(f"resumed at iteration {trainer.iteration}, {progress['train_s'] / 60:.1f} min")
    print(
        f"clips: {', '.join(c.name for c in data.clips[0])} "
        f"({sum(c.num_frames for c in data.clips[0])} frames); envs {args.envs}, horizon "
        f"{config.ppo.horizon}, {config.ppo.epochs} epochs, lr {config.ppo.learning_rate}, std "
        f"{config.ppo.action_std}, gamma {config.ppo.gamma}, net {config.network.hidden_sizes}, "
        f"value sees partner {track.value_sees_partner}, hard starts {track.hard_start_share}, "
        f"{config.env.threads} threads",
        flush=True,
    )
    steps_per_iteration = config.env.num_envs * config.ppo.horizon
    session = time.perf_counter()
    wall_before = progress["wall_s"]
    clock = time.perf_counter()
    gate = None
    try:
        while trainer.iteration < config.iterations and ("held" not in progress or args.keep_going):
            metrics = trainer.iterate()
            now = time.perf_counter()
            progress["train_s"] += now - clock
            clock = now
            done = trainer.iteration
            if done % args.gate_every == 0:
                gate = track_gate(trainer.nets.policy, data, config)
                row = {
                    "iteration": done,
                    "env_steps": done * steps_per_iteration,
                    "minutes": progress["train_s"] / 60,
                    "wall_minutes": (wall_before + time.perf_counter() - session) / 60,
                    "finished_pct": gate.finished_pct,
                    "body_error_cm": gate.body_error_cm,
                    "root_error_cm": gate.root_error_cm,
                    "met": gate_met(gate, track),
                    "train_body_error_cm": metrics["body_error_cm"],
                    "train_reward": metrics["reward_total"],
                    "episode_length_s": metrics.get("episode_length_s", float("nan")),
                }
                progress["gates"].append(row)
                print(
                    f"it {done:5d}  {row['env_steps'] / 1e6:6.2f} M steps  {row['minutes']:6.1f} "
                    f"min ({row['wall_minutes']:5.1f} wall)  gate: {gate.finished_pct:5.1f} % "
                    f"finished, {gate.body_error_cm:5.2f} cm body, {gate.root_error_cm:5.2f} cm "
                    f"root {'met' if row['met'] else '   '} (training: reward "
                    f"{row['train_reward']:.3f}, body {row['train_body_error_cm']:.2f} cm, "
                    f"episodes {row['episode_length_s']:.2f} s)",
                    flush=True,
                )
                clock = time.perf_counter()  # the gate's own time is not training time
                if row["met"] and "reached" not in progress:
                    progress["reached"] = row
                held_now = gate_held([g["met"] for g in progress["gates"]], track)
                if held_now and "held" not in progress:
                    progress["held"] = row
                    print(
                        f"gate held at iteration {done}, {row['wall_minutes']:.1f} min wall",
                        flush=True,
                    )
            wall = wall_before + time.perf_counter() - session
            over = wall > args.minutes * 60
            stop = over or ("held" in progress and not args.keep_going)
            if done % args.checkpoint_every == 0 or stop:
                progress["wall_s"] = wall
                _write(checkpoint, trainer.checkpoint())
                _write(progress_file, json.dumps(progress, indent=1).encode())
            if stop:
                break
    finally:
        trainer.close()
    gates = progress["gates"]
    if gate is None or not gates or gates[-1]["iteration"] != trainer.iteration:
        gate = track_gate(trainer.nets.policy, data, config)
    for row in gate.rows:
        print(
            f"  agent {row.agent} {row.clip:20s} {'finished' if row.finished else 'failed  '} "
            f"{row.frames:3d} frames  body {row.body_error_cm:5.2f} cm  "
            f"root {row.root_error_cm:5.2f} cm"
        )
    first = progress.get("reached")
    held = progress.get("held")
    print(
        f"seed {seed}: iterations {trainer.iteration}, "
        f"{trainer.iteration * steps_per_iteration / 1e6:.2f} M env steps, "
        f"{progress['train_s'] / 60:.1f} min of training, {progress['wall_s'] / 60:.1f} wall; "
        f"gate {'met' if gate_met(gate, track) else 'not met'} now "
        f"({gate.finished_pct:.1f} % finished, {gate.body_error_cm:.2f} cm body, "
        f"{gate.root_error_cm:.2f} cm root)"
        + (f", first met at {first['wall_minutes']:.1f} min" if first else "")
        + (f", held at {held['wall_minutes']:.1f} min wall" if held else ", not held"),
        flush=True,
    )
    if held is None or held["wall_minutes"] > args.minutes:
        return None
    return float(held["wall_minutes"])


if __name__ == "__main__":
    main()
