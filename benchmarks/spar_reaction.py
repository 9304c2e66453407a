"""Does the live opponent answer its partner? Its facing, the distance it keeps and where it
punches, against a partner that circles it and steps in and out.

    python benchmarks/spar_reaction.py [--data DIR] [--opponent FOLDER] [--partner lifted]

On a data directory where `make demo` ran (or any with a processed video and an exported
opponent): the newest exported adversary (`DATA/opponents/*-adversary`, or `--opponent`, of any
kind: MAAIP's or the matched opponent, `ringside export --run TRACKER --matched`) and, as the
still guard, an untrained policy exported on the same bones and physics whose mean is the
dataset's stance (it stands in it, as the evaluation's still guard does; tests/opponents.py).
Each is served by a real `ringside spar-server`, and examples/spar_client.py streams the partner
live, `SESSIONS` sessions each way round of `SECONDS`:

- the scripted partner (the default): the first video's lifted partner (the footage's other
  fighter, `ringside export-motion`) holding its first pose, placed where the server put the
  partner facing the opponent, carried round the opponent's start at `ORBIT_DEG_S` (`--orbit`)
  and stepping in to `NEAR_M` and out to `FAR_M` from it at `APPROACH_M_S` (`--approach`);
- `--partner lifted`: that lifted motion as filmed, looped and carried round the same way.

Per opponent: the mean |facing error| (its heading against the bearing from its pelvis to the
partner's), mean and range over the sessions, beside that of a fighter that kept its first
heading (never turning: the degenerate answer); how far it turned against how far the bearing
went round (a restart's jump left out); falls and restarts (a restart puts it back facing the
partner, which flatters the facing error: counted so that it is seen); the share of steps the two
touched; the distance it kept (pelvis to pelvis), its Wasserstein-1 against the distance
between the fighters in the dataset's train footage of that fighter; and its punches a minute
with the partner within `REACH_M` (pelvis to pelvis) and beyond it, labelled by the evaluation's
code (`label_fighter`) on its motion as the states carried it, beside the footage's labelled the
same way. Last line: ``spar_facing_error_trained: <deg> deg``.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import tempfile
from dataclasses import fields
from pathlib import Path

import mujoco
import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
# The tests' opponent folders and server (tests/opponents.py, free of conftest's set-up) and the
# example client.
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO / "examples"))

from opponents import spar_server, untrained_opponents  # noqa: E402
from spar_client import fighter, spar_session, summary  # noqa: E402

from flows.cli import main as ringside  # noqa: E402
from models.arena.config import EnvConfig  # noqa: E402
from models.arena.mjcf import arena_mjcf  # noqa: E402
from models.humanoid.bvh import read_bvh  # noqa: E402
from storage.db import connect  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.config import build  # noqa: E402
from tasks.dataset.config import DatasetConfig, PunchConfig  # noqa: E402
from tasks.dataset.demonstrations import load_demonstrations  # noqa: E402
from tasks.dataset.store import ROLES, dataset_info, footage_clips  # noqa: E402
from tasks.evaluate.metrics import footage_bouts, label_fighter, wasserstein1  # noqa: E402
from tasks.opponent.folder import Opponent, load_opponent  # noqa: E402

SECONDS = 16.0
ORBIT_DEG_S = 10.0
NEAR_M, FAR_M, APPROACH_M_S = 0.6, 3.0, 0.6
SESSIONS = 3  # each way round
# Within reach: pelvis to pelvis, an arm's length (0.5-0.6 m) and the two bodies' depth.
REACH_M = 1.0


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


def still_guard_like(opponent: Opponent, data: Path, root: Path) -> Path:
    """An untrained policy whose mean is the stance of the opponent's dataset (the evaluation's
    still guard, `ReferenceMotions.stance`), on the folder's bones and physics, in its slot.
    Not the folder's own guard: a matched opponent's is its footage's first frame, mid-stride,
    which a fighter cannot hold still (it fell every 0.8 s on the demo's)."""
    with connect(data_paths(data).db, read_only=True) as con:
        stance = load_demonstrations(con, opponent.manifest["dataset_key"]).reference.stance
    if stance is None:
        raise SystemExit(f"the dataset of {opponent.folder} has no stance to stand in")
    known = {f.name for f in fields(EnvConfig)}
    env = {k: v for k, v in opponent.manifest["env"].items() if k in known}
    env.update(num_envs=32, threads=1)
    return untrained_opponents(root, opponent.bones, stance, EnvConfig(**env))[opponent.agent]


def sessions(folder: Path, qpos: np.ndarray, fps: float, data: Path, scripted: bool) -> list:
    """``2 SESSIONS`` sessions against the partner (module docstring): (summary, recording)."""
    motion = np.tile(qpos[:1], (round(SECONDS * fps), 1)) if scripted else qpos
    loops = max(1, round(SECONDS * fps / len(motion)))
    approach = (NEAR_M, FAR_M, APPROACH_M_S) if scripted else None
    out = []
    with spar_server(folder, data) as (url, _, _):
        for k in range(2 * SESSIONS):
            rate = ORBIT_DEG_S if k % 2 == 0 else -ORBIT_DEG_S
            recording = asyncio.run(
                spar_session(url, motion, fps, loops=loops, orbit_deg_s=rate, approach=approach)
            )
            facts = summary(recording, motion="-", fps=fps, loops=loops, bones_from="-")
            out.append((facts, recording))
    return out


def spacing(
    clips: list[tuple[np.ndarray, np.ndarray]], bones, punch: PunchConfig, fps: float
) -> tuple[np.ndarray, np.ndarray]:
    """Of a fighter's ``clips`` (its qpos (T, 35), the other's) on ``bones`` (its, the other's):
    the pelvis-to-pelvis distance of every frame, and at the peak of each of its punches
    (`label_fighter`)."""
    model = mujoco.MjModel.from_xml_string(arena_mjcf(bones))
    bouts = footage_bouts(model, clips, round(fps))
    labelled = label_fighter(bouts, 0, model=model, bones=bones[0], punch=punch)
    distances, at_peaks = [], []
    for (own, other), punches in zip(clips, labelled.punches, strict=True):
        apart = np.linalg.norm(own[:, :2] - other[:, :2], axis=1)
        distances.append(apart)
        at_peaks.append(apart[[p.peak for p in punches]])
    return np.concatenate(distances), np.concatenate(at_peaks)


def reach_rates(apart: np.ndarray, at_peaks: np.ndarray, fps: float) -> dict[str, float]:
    """Punches a minute with the other fighter within `REACH_M` and beyond it: the punches whose
    peak was there over the time spent there (NaN where no time was)."""
    rates = {}
    for name, near in (("in_reach", True), ("out_of_reach", False)):
        minutes = np.sum((apart <= REACH_M) == near) / fps / 60.0
        count = np.sum((at_peaks <= REACH_M) == near)
        rates[name] = count / minutes if minutes else float("nan")
    return rates


def footage_spacing(
    data: Path, opponent: Opponent, fps: float
) -> tuple[np.ndarray, np.ndarray, PunchConfig]:
    """`spacing` of the opponent's fighter in its dataset's train footage (each clip on its
    fighter's own bones, as the evaluation lays footage), and the dataset's punch settings."""
    key, role = opponent.manifest["dataset_key"], ROLES[opponent.agent]
    with connect(data_paths(data).db, read_only=True) as con:
        clips = footage_clips(con, key, role)
        punch = build(DatasetConfig, dataset_info(con, key).config, section="dataset").punch
    if not clips:
        raise SystemExit(f"dataset {key[:12]} holds no train footage of its {role}")
    parts = [
        spacing(
            [(c.qpos, c.other_qpos) for c in clips if c.bones == bones], (bones, bones), punch, fps
        )
        for bones in dict.fromkeys(c.bones for c in clips)
    ]
    apart, at_peaks = (np.concatenate(p) for p in zip(*parts, strict=True))
    return apart, at_peaks, punch


def session_spacing(opponent: Opponent, runs: list, punch: PunchConfig, fps: float):
    """`spacing` of the served opponent over the sessions' states."""
    clips = []
    for _, recording in runs:
        states = recording.states
        own = np.array([fighter(s, "opponent")["qpos"] for s in states], dtype=np.float64)
        other = np.array([fighter(s, "partner")["qpos"] for s in states], dtype=np.float64)
        clips.append((own, other))
    bones = (opponent.bones[opponent.agent], opponent.bones[1 - opponent.agent])
    return spacing(clips, bones, punch, fps)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, help="data directory (default: Ringside's)")
    parser.add_argument("--opponent", type=Path, help="opponent folder (default: the newest)")
    parser.add_argument("--partner", choices=("scripted", "lifted"), default="scripted")
    args = parser.parse_args()
    data = data_paths(args.data).root
    trained = args.opponent or newest_adversary(data)
    opponent = load_opponent(trained)
    scripted = args.partner == "scripted"
    with tempfile.TemporaryDirectory(prefix="ringside-spar-reaction-") as tmp:
        tmp = Path(tmp)
        fps, qpos = read_bvh(partner_motion(data, tmp / "motion").read_text())
        folders = {"trained": trained, "guard": still_guard_like(opponent, data, tmp / "guard")}
        results = {
            name: sessions(folder, qpos, fps, tmp / f"{name}-data", scripted)
            for name, folder in folders.items()
        }
    filmed, filmed_peaks, punch = footage_spacing(data, opponent, fps)
    kept = {name: session_spacing(opponent, runs, punch, fps) for name, runs in results.items()}
    partner = (
        f"a scripted partner holding the lifted partner's first pose, stepping in to {NEAR_M} m "
        f"and out to {FAR_M} m at {APPROACH_M_S} m/s"
        if scripted
        else "the lifted partner, looped"
    )
    print(
        f"opponent {trained.name} ({opponent.kind}) against {partner}, carried round it at "
        f"{ORBIT_DEG_S:.0f} deg/s, {SESSIONS} sessions of {SECONDS:.0f} s each way round"
    )
    print(
        "opponent    facing error (mean, range)   never turning (mean)   turned / bearing moved"
        "   falls  restarts  in contact"
    )
    for name, runs in results.items():
        facts = [f for f, _ in runs]
        error = np.array([r["facing"]["mean_abs_deg"] for r in facts])
        still = np.array([r["facing"]["still_mean_abs_deg"] for r in facts])
        turned = np.array([abs(r["opponent_turned_deg"]) for r in facts])
        moved = np.array([abs(r["bearing_moved_deg"]) for r in facts])
        falls = sum(r["falls"]["opponent"] for r in facts)
        resets = sum(r["resets"] for r in facts)
        touching = np.mean([r["contact_share"] for r in facts])
        print(
            f"{name:10s}  {error.mean():6.1f} deg ({error.min():.1f}-{error.max():.1f})"
            f"       {still.mean():6.1f} deg            {turned.mean():5.0f} / "
            f"{moved.mean():3.0f} deg      {falls:5d}  {resets:8d}  {touching:10.0%}"
        )
    print(
        f"\ndistance kept (pelvis to pelvis, m) and punches a minute within {REACH_M} m and "
        "beyond, against the train footage of its fighter"
    )
    print("who         distance mean (p10-p90)   W1 to footage   punches/min in reach / beyond")
    for name, (apart, at_peaks) in {"footage": (filmed, filmed_peaks), **kept}.items():
        rates = reach_rates(apart, at_peaks, fps)
        w1 = "" if name == "footage" else f"{wasserstein1(apart, filmed):.2f} m"
        print(
            f"{name:10s}  {apart.mean():5.2f} ({np.percentile(apart, 10):.2f}-"
            f"{np.percentile(apart, 90):.2f})        {w1:>13s}   "
            f"{rates['in_reach']:8.1f} / {rates['out_of_reach']:.1f}"
        )
    error = np.mean([f["facing"]["mean_abs_deg"] for f, _ in results["trained"]])
    print(f"spar_facing_error_trained: {error:.1f} deg")


if __name__ == "__main__":
    main()
