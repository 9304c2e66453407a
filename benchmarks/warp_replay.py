"""A trained tracker replaying a dataset's held-out clips as filmed, on MuJoCo and on MuJoCo Warp.

The same policy in the two physics (`train.env.stepping` 'rollout' and 'warp', Warp on the CPU
here): each clip's gate figures (finished, body and root errors, `models.tracking.gate`) and how
far apart the two replays' bodies end. Needs a data directory whose dataset has a finished
tracker run (`ringside train --dataset KEY --train-objective track`), e.g. the synthetic
adversary's (`ringside synthetic-adversary`).

    python benchmarks/warp_replay.py --data DIR [--dataset KEY] [--stills FILE.png]
    python benchmarks/warp_replay.py [--gate-folder FOLDER]

Without ``--data``, seed 0's tracker of `benchmarks/tracker_gate.py`'s folder (`make bench` runs it
first) replays DeepMimic's clips, each fighter from its clip's first frame at its own place.

``--stills`` saves three frames of one clip's replay in each physics, MuJoCo above, Warp below.

The last line is ``warp_replay_root_diff: <mm> mm``: the largest difference of a pelvis
coordinate between the two replays, over every clip, fighter and frame.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

# As `ringside` sets it (flows/cli/environment.py): before MuJoCo is imported, to render.
os.environ.setdefault("MUJOCO_GL", "egl")

import cv2  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import tracker_gate  # noqa: E402  (beside this file)

from models.arena.mjcf import NUM_AGENTS, arena_mjcf  # noqa: E402
from models.humanoid.boxer import BoneLengths  # noqa: E402
from models.maaip.trainer import checkpoint_policy  # noqa: E402
from models.tracking.gate import Played, gate_of, play_clips  # noqa: E402
from storage.artifacts import read_bytes  # noqa: E402
from storage.db import connect  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.config import build  # noqa: E402
from tasks.train.config import TrainConfig  # noqa: E402
from tasks.train.store import finished_runs  # noqa: E402
from tasks.train.tracker import footage_tracking  # noqa: E402

ROOTS = [0, 1, 2, 35, 36, 37]


def _within_runs(played: Played) -> np.ndarray:
    """`Played.qpos` with each agent's coordinates NaN after its run ended: `play_clips` steps
    every arena until the last run ends, and what a body does after its clip's end (it holds the
    last frame's targets, often mid-stride, and falls) is not the tracking. An arena whose agent
    has no clip of its own there (fewer clips) is NaN throughout for that agent."""
    qpos = played.qpos.copy()
    width = qpos.shape[-1] // NUM_AGENTS
    for a in range(NUM_AGENTS):
        runs = [row.frames for row in played.rows if row.agent == a]  # its clip k in arena k
        for k, end in enumerate(runs + [0] * (qpos.shape[1] - len(runs))):
            qpos[end:, k, a * width : (a + 1) * width] = np.nan
    return qpos


def _stills(model, qpos: np.ndarray, label: str) -> np.ndarray:
    """Frames 0, middle and last of one replay (T, nq; NaN after its end) side by side."""
    last = int(np.flatnonzero(np.isfinite(qpos).all(axis=1))[-1])
    model.vis.global_.offwidth, model.vis.global_.offheight = 640, 360
    model.vis.quality.shadowsize = 0
    renderer, data = mujoco.Renderer(model, 360, 640), mujoco.MjData(model)
    frames = []
    for t in (0, last // 2, last):
        data.qpos[:] = qpos[t]
        mujoco.mj_forward(model, data)
        renderer.update_scene(data, camera="side")
        image = np.ascontiguousarray(renderer.render()[:, :, ::-1])
        text = f"{'MuJoCo' if label == 'rollout' else 'MuJoCo Warp'}  t = {t / 30:.1f} s"
        cv2.putText(image, text, (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2)
        frames.append(image)
    renderer.close()
    return np.concatenate(frames, axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, help="a data directory with a tracker run")
    parser.add_argument(
        "--gate-folder",
        type=Path,
        default=tracker_gate.DEFAULT_FOLDER,
        help="without --data: benchmarks/tracker_gate.py's folder",
    )
    parser.add_argument("--dataset", help="a dataset key (prefix); default: the newest tracker's")
    parser.add_argument("--stills", type=Path, help="a PNG of one clip's replay in both physics")
    parser.add_argument("--clip", type=int, default=3, help="the clip --stills shows")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.data is None:
        blob = args.gate_folder / "seed-0" / "checkpoint.pt"
        if not blob.exists():
            sys.exit(f"{blob}: missing; run benchmarks/tracker_gate.py first (make bench does)")
        gate_args = tracker_gate.parser().parse_args([str(args.gate_folder)])
        config = tracker_gate.tracking_config(gate_args)
        assets = data_paths().assets
        data = tracker_gate.synthetic_adversary(assets, BoneLengths(), float(config.env.policy_hz))
        policy, bones = checkpoint_policy(blob.read_bytes(), config)
        filmed = False
        print(f"tracker of {args.gate_folder} on DeepMimic's clips")
    else:
        paths = data_paths(args.data)
        with connect(paths.db, read_only=True) as con:
            runs = [r for r in finished_runs(con, "TRUE", []) if r.objective == "track"]
            if args.dataset:
                runs = [r for r in runs if r.dataset_key.startswith(args.dataset)]
            if not runs:
                sys.exit(f"{paths.db}: no finished tracker run")
            run = runs[-1]
            config = build(TrainConfig, run.config, section="train")
            data = footage_tracking(con, run.dataset_key, fps=config.env.policy_hz)["validation"]
        policy, bones = checkpoint_policy(read_bytes(paths.artifacts, run.artifact), config)
        filmed = True
        print(f"tracker {run.run_key[:12]} on dataset {run.dataset_key[:12]}, held-out clips")
    played = {}
    for stepping in ("rollout", "warp"):
        env = dataclasses.replace(config.env, stepping=stepping)
        start = time.perf_counter()
        played[stepping] = play_clips(
            policy, data, dataclasses.replace(config, env=env), as_filmed=filmed
        )
        gate = gate_of(played[stepping].rows)
        print(
            f"{stepping}: {gate.finished_pct:.1f} % finished, body {gate.body_error_cm:.2f} cm, "
            f"root {gate.root_error_cm:.2f} cm over {len(played[stepping].rows)} clip tracks "
            f"({time.perf_counter() - start:.0f} s)"
        )
    mujoco_qpos, warp_qpos = (_within_runs(played[s]) for s in ("rollout", "warp"))
    apart = np.abs(mujoco_qpos - warp_qpos)
    print(f"largest joint coordinate apart: {np.nanmax(apart):.4f}")
    if args.stills:
        model = mujoco.MjModel.from_xml_string(arena_mjcf(bones, timestep=config.env.timestep))
        rows = [
            _stills(model, qpos[:, args.clip], s)
            for s, qpos in (("rollout", mujoco_qpos), ("warp", warp_qpos))
        ]
        cv2.imwrite(str(args.stills), np.concatenate(rows, axis=0))
        print(f"stills of clip {args.clip}: {args.stills}")
    print(f"warp_replay_root_diff: {1000 * np.nanmax(apart[..., ROOTS]):.2f} mm")


if __name__ == "__main__":
    main()
