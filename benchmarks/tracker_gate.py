"""The tracker gate (issue 32): train a tracker on the synthetic adversary, gate it now and then.

The synthetic adversary's clips: DeepMimic's walk and punch and the walker's forward walk and
four turns (`tasks.deepmimic`), retargeted onto `BoneLengths()`, tracked by both fighters of
every arena (`models.tracking`). The trainer is the project's own (`Trainer` with
objective 'track'); this script adds the tracking PPO settings below, a checkpoint every
``--checkpoint-every`` iterations in FOLDER (``checkpoint.pt``, and ``progress.json`` with the
training seconds and the gate figures so far), and `track_gate` every ``--gate-every``:
every clip from its first frame, both agents, acting on the policy's mean. Stopped (Ctrl-C, a
kill, ``--minutes``) and started again on the same FOLDER it resumes from the checkpoint, as
the train stage does, and its clocks go on from the seconds saved there (training alone, and
wall time with the gates).

Gate: >= 90 % of clips finished, mean body error <= 5 cm, root error <= 10 cm. The run ends
when it is first met (unless ``--keep-going``), at ``--iterations`` or after ``--minutes`` of
this session; ``progress.json`` keeps the first gate that met it.
Each gate prints one line; the last line is
``tracker_gate: <finished> % finished, <body> cm body, <root> cm root``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
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
from models.tracking.gate import Gate, track_gate  # noqa: E402
from storage.assets import pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.deepmimic import WALKER_CLIPS, clip_path, load_deepmimic, retarget  # noqa: E402
from tasks.train.config import TrainConfig  # noqa: E402

CLIPS = ("walk", "punch", *WALKER_CLIPS)
# Where `make bench` keeps the run (benchmarks/warp_replay.py replays its tracker).
DEFAULT_FOLDER = Path("data/bench/tracker_gate")
GATE = {"finished_pct": 90.0, "body_error_cm": 5.0, "root_error_cm": 10.0}


def synthetic_adversary(assets: Path, bones: BoneLengths, fps: float) -> TrackingData:
    """The seven clips on ``bones``, for both agents."""
    clips = {
        name: retarget(load_deepmimic(clip_path(assets, name)), bones, fps=fps) for name in CLIPS
    }
    return tracking_data((clips, clips), (bones, bones), fps=fps, key="synthetic-adversary")


def passed(gate: Gate) -> bool:
    return (
        gate.finished_pct >= GATE["finished_pct"]
        and gate.body_error_cm <= GATE["body_error_cm"]
        and gate.root_error_cm <= GATE["root_error_cm"]
    )


def tracking_config(args: argparse.Namespace) -> TrainConfig:
    """The project's defaults with the tracking PPO settings of this benchmark."""
    base = TrainConfig()
    return TrainConfig(
        objective="track",
        seed=args.seed,
        device=args.device,
        iterations=args.iterations,
        ppo=dataclasses.replace(
            base.ppo,
            learning_rate=args.learning_rate,
            action_std=args.action_std,
            arm_action_std=0.0,
            gamma=args.gamma,
            # As many minibatches per epoch as with the default 64 arenas.
            minibatch_size=base.ppo.minibatch_size * args.envs // base.env.num_envs,
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
    parser.add_argument("--minutes", type=float, default=60.0, help="this session's budget")
    parser.add_argument("--iterations", type=int, default=100_000, help="at most this many")
    parser.add_argument("--checkpoint-every", type=int, default=20)
    parser.add_argument("--gate-every", type=int, default=20)
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--threads", type=int, default=1, help="cores (physics and torch)")
    parser.add_argument("--stepping", choices=STEPPINGS, default=TrainConfig().env.stepping)
    parser.add_argument("--device", default="cpu", help="cpu or cuda (networks and Warp)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--learning-rate", type=float, default=1e-4)
    parser.add_argument("--action-std", type=float, default=0.05, help="every action's std")
    parser.add_argument("--gamma", type=float, default=0.95, help="DeepMimic's 0.95")
    parser.add_argument(
        "--keep-going", action="store_true", help="train on after the gate is met (the curve)"
    )
    return parser


def main() -> None:
    args = parser().parse_args()
    torch.set_num_threads(args.threads)

    assets = data_paths().assets
    pull(assets, dev=True, log=lambda _line: None)
    config = tracking_config(args)
    data = synthetic_adversary(assets, BoneLengths(), float(config.env.policy_hz))
    args.folder.mkdir(parents=True, exist_ok=True)
    checkpoint, progress_file = args.folder / "checkpoint.pt", args.folder / "progress.json"
    trainer = Trainer(config, data)
    progress: dict = {"train_s": 0.0, "wall_s": 0.0, "gates": []}
    if checkpoint.exists():
        trainer.restore(checkpoint.read_bytes())
        progress = json.loads(progress_file.read_text())
        print(f"resumed at iteration {trainer.iteration}, {progress['train_s'] / 60:.1f} min")
    print(
        f"clips: {', '.join(c.name for c in data.clips[0])} "
        f"({sum(c.num_frames for c in data.clips[0])} frames); envs {args.envs}, horizon "
        f"{config.ppo.horizon}, lr {config.ppo.learning_rate}, std {config.ppo.action_std}, "
        f"gamma {config.ppo.gamma}, net {config.network.hidden_sizes}",
        flush=True,
    )
    steps_per_iteration = config.env.num_envs * config.ppo.horizon
    session = time.perf_counter()
    wall_before = progress["wall_s"]
    clock = time.perf_counter()
    gate = None
    try:
        while trainer.iteration < config.iterations:
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
                    "train_body_error_cm": metrics["body_error_cm"],
                    "train_reward": metrics["reward_total"],
                    "episode_length_s": metrics.get("episode_length_s", float("nan")),
                }
                progress["gates"].append(row)
                print(
                    f"it {done:5d}  {row['env_steps'] / 1e6:6.2f} M steps  {row['minutes']:6.1f} "
                    f"min  gate: {gate.finished_pct:5.1f} % finished, {gate.body_error_cm:5.2f} "
                    f"cm body, {gate.root_error_cm:5.2f} cm root  (training: reward "
                    f"{row['train_reward']:.3f}, body {row['train_body_error_cm']:.2f} cm, "
                    f"episodes {row['episode_length_s']:.2f} s)",
                    flush=True,
                )
                clock = time.perf_counter()  # the gate's own time is not training time
            over = time.perf_counter() - session > args.minutes * 60
            reached = gate is not None and done % args.gate_every == 0 and passed(gate)
            if reached and "reached" not in progress:
                progress["reached"] = row
                print(f"gate reached at iteration {done}, {row['minutes']:.1f} min", flush=True)
            reached = reached and not args.keep_going
            if done % args.checkpoint_every == 0 or over or reached:
                progress["wall_s"] = wall_before + time.perf_counter() - session
                _write(checkpoint, trainer.checkpoint())
                _write(progress_file, json.dumps(progress, indent=1).encode())
            if over or reached:
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
    print(
        f"iterations {trainer.iteration}, {trainer.iteration * steps_per_iteration / 1e6:.2f} M "
        f"env steps, {progress['train_s'] / 60:.1f} min of training; gate "
        f"{'met' if passed(gate) else 'not met'} now"
        + (
            f", first met at iteration {progress['reached']['iteration']} "
            f"({progress['reached']['minutes']:.1f} min)"
            if "reached" in progress
            else ""
        )
    )
    print(
        f"tracker_gate: {gate.finished_pct:.1f} % finished, {gate.body_error_cm:.2f} cm body, "
        f"{gate.root_error_cm:.2f} cm root"
    )


if __name__ == "__main__":
    main()
