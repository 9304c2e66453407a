"""Does the live opponent follow its partner? Its facing against a fighter that never turns.

    python benchmarks/spar_reaction.py [--data DIR] [--opponent FOLDER]

On a data directory where `make demo` ran (or any with a processed video and an exported
adversary): the newest exported adversary (`DATA/opponents/*-adversary`, or `--opponent`) and,
as the untrained baseline, an untrained policy exported on the same bones, guard and physics
(its mean is its guard: where training starts; tests/opponents.py). Each is served by a real
`ringside spar-server`, and the first video's lifted partner (the footage's other fighter, as
`ringside export-motion` writes it) is streamed live as the partner by examples/spar_client.py:
looped to `SECONDS`, placed where the server put the partner and facing the opponent, and
carried round the opponent's start at `ORBIT_DEG_S` (`--orbit`), `SESSIONS` sessions each way
round, so that an opponent that keeps facing its partner must turn.

Per opponent: the mean |facing error| (its heading against the bearing from its pelvis to the
partner's) over each session, as mean and range over the sessions; beside it, from the same
sessions, the error of a fighter that kept its first heading (never turning: the degenerate
answer); how far it turned against how far the bearing went round (a restart's jump left out);
falls and restarts (a restart puts it back facing the partner, which flatters the facing error:
counted so that it is seen); the share of steps the two fighters touched (a partner that shoves
the opponent round turns it without any reaction of its own).
Last line: ``spar_facing_error_trained: <deg> deg``.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import tempfile
from dataclasses import fields
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
# The tests' opponent folders and server (tests/opponents.py, free of conftest's set-up) and the
# example client.
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO / "examples"))

from opponents import spar_server, untrained_opponents  # noqa: E402
from spar_client import spar_session, summary  # noqa: E402

from flows.cli import main as ringside  # noqa: E402
from models.arena.config import EnvConfig  # noqa: E402
from models.humanoid.bvh import read_bvh  # noqa: E402
from storage.db import connect  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.opponent.folder import load_opponent  # noqa: E402

SECONDS = 12.0
ORBIT_DEG_S = 10.0
SESSIONS = 3  # each way round


def partner_motion(data: Path, out: Path) -> Path:
    """The first video's lifted partner as BVH (its longest unbroken stretch)."""
    with connect(data_paths(data).db, read_only=True) as con:
        (video,) = con.execute(
            "SELECT video_id FROM videos ORDER BY registered_at LIMIT 1"
        ).fetchone()
    if ringside(["--data", str(data), "export-motion", "--video", video, "--out", str(out)]) != 0:
        raise SystemExit(f"could not export the lifted motion of video {video}")
    files = sorted(out.glob("opponent-*.bvh"), key=lambda f: -len(f.read_text()))
    if not files:
        raise SystemExit(f"video {video} has no lifted partner")
    return files[0]


def newest_adversary(data: Path) -> Path:
    folders = sorted(
        (data_paths(data).root / "opponents").glob("*-adversary"), key=lambda f: f.stat().st_mtime
    )
    if not folders:
        raise SystemExit(f"no exported adversary in {data}/opponents: run `make demo` first")
    return folders[-1]


def untrained_like(folder: Path, root: Path) -> Path:
    """An untrained policy on the opponent folder's bones, guard and physics, in its slot."""
    opponent = load_opponent(folder)
    known = {f.name for f in fields(EnvConfig)}
    env = {k: v for k, v in opponent.manifest["env"].items() if k in known}
    env.update(num_envs=32, threads=1)
    return untrained_opponents(root, opponent.bones, opponent.guard, EnvConfig(**env))[
        opponent.agent
    ]


def sessions(folder: Path, motion: Path, data: Path) -> list[dict]:
    fps, qpos = read_bvh(motion.read_text())
    loops = max(1, round(SECONDS * fps / len(qpos)))
    out = []
    with spar_server(folder, data) as (url, _, _):
        for k in range(2 * SESSIONS):
            rate = ORBIT_DEG_S if k % 2 == 0 else -ORBIT_DEG_S
            recording = asyncio.run(spar_session(url, qpos, fps, loops=loops, orbit_deg_s=rate))
            out.append(summary(recording, motion=str(motion), fps=fps, loops=loops, bones_from="-"))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, help="data directory (default: Ringside's)")
    parser.add_argument("--opponent", type=Path, help="opponent folder (default: the newest)")
    args = parser.parse_args()
    data = data_paths(args.data).root
    trained = args.opponent or newest_adversary(data)
    with tempfile.TemporaryDirectory(prefix="ringside-spar-reaction-") as tmp:
        tmp = Path(tmp)
        motion = partner_motion(data, tmp / "motion")
        folders = {"trained": trained, "untrained": untrained_like(trained, tmp / "untrained")}
        results = {
            name: sessions(folder, motion, tmp / f"{name}-data") for name, folder in folders.items()
        }
    print(
        f"opponent {trained.name} against the lifted partner of {motion.name}, looped to "
        f"{SECONDS:.0f} s and carried round it at {ORBIT_DEG_S:.0f} deg/s, {SESSIONS} sessions "
        "each way round"
    )
    print(
        "opponent    facing error (mean, range)   never turning (mean)   turned / bearing moved"
        "   falls  restarts  in contact"
    )
    for name, runs in results.items():
        error = np.array([r["facing"]["mean_abs_deg"] for r in runs])
        still = np.array([r["facing"]["still_mean_abs_deg"] for r in runs])
        turned = np.array([abs(r["opponent_turned_deg"]) for r in runs])
        moved = np.array([abs(r["bearing_moved_deg"]) for r in runs])
        falls = sum(r["falls"]["opponent"] for r in runs)
        resets = sum(r["resets"] for r in runs)
        touching = np.mean([r["contact_share"] for r in runs])
        print(
            f"{name:10s}  {error.mean():6.1f} deg ({error.min():.1f}-{error.max():.1f})"
            f"       {still.mean():6.1f} deg            {turned.mean():5.0f} / "
            f"{moved.mean():3.0f} deg      {falls:5d}  {resets:8d}  {touching:10.0%}"
        )
    trained_error = np.mean([r["facing"]["mean_abs_deg"] for r in results["trained"]])
    print(f"spar_facing_error_trained: {trained_error:.1f} deg")


if __name__ == "__main__":
    main()
