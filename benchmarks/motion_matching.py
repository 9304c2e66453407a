"""The motion matcher's search: scipy's KD-tree against the brute force beside it.

    python benchmarks/motion_matching.py [--minutes 10] [--queries 64]

Builds a database of about ``--minutes`` of a fighter's footage (DeepMimic's clips on the default
body, each played with its partner at a spread of distances and bearings, so that no two copies
are the same frames), then times one search of ``--queries`` queries (one per arena, as the
matched opponent searches all its arenas at once): each query a database frame moved by
noise of 0.3 of each feature's spread, playing half the time. Both searches must return the
same frames. CPU time per search, best of 5, one thread. DReCon's database was 10 minutes of
mocap. Last line: the brute force's time over the KD-tree's.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import timeit  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.humanoid.boxer import BoneLengths  # noqa: E402
from models.tracking.clips import reference_clip  # noqa: E402
from models.tracking.matching import motion_database  # noqa: E402
from storage.assets import pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.deepmimic import CLIPS, WALKER_CLIPS, clip_path, load_deepmimic, retarget  # noqa: E402

FPS = 30.0


def cpu_seconds(fn) -> float:
    number = 1
    while timeit.timeit(fn, number=number, timer=time.process_time) < 0.05:
        number *= 2
    return min(timeit.repeat(fn, number=number, repeat=5, timer=time.process_time)) / number


def partner(qpos: np.ndarray, gap_m: float, bearing: float) -> np.ndarray:
    """A partner holding the clip's first pose ``gap_m`` from its pelvis at ``bearing`` (rad
    from its facing), turned to face it."""
    first = qpos[0].copy()
    root = Rotation.from_quat(first[3:7], scalar_first=True)
    ahead = Rotation.from_euler("z", bearing).apply(root.apply([1.0, 0.0, 0.0]) * [1, 1, 0])
    first[:2] += gap_m * ahead[:2] / np.linalg.norm(ahead[:2])
    first[3:7] = (Rotation.from_euler("z", np.pi + bearing) * root).as_quat(scalar_first=True)
    return np.tile(first, (len(qpos), 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--queries", type=int, default=64)
    args = parser.parse_args()
    assets = data_paths().assets
    pull(assets, dev=True, log=lambda _line: None)
    bones = BoneLengths()
    motions = [retarget(load_deepmimic(clip_path(assets, n))) for n in (*CLIPS, *WALKER_CLIPS)]
    rng = np.random.default_rng(0)
    own, partners, frames = [], [], 0
    while frames < args.minutes * 60 * FPS:
        k = len(own)
        qpos = motions[k % len(motions)]
        gap, bearing = rng.uniform(0.5, 4.0), rng.uniform(-np.pi, np.pi)
        own.append(reference_clip(f"c{k}", qpos, bones, fps=FPS))
        partners.append(reference_clip(f"p{k}", partner(qpos, gap, bearing), bones, fps=FPS))
        frames += len(qpos)
    started = time.perf_counter()
    db = motion_database(own, partners, fps=FPS)
    built = time.perf_counter() - started
    picked = rng.choice(db.candidates, args.queries)
    spread = db.features[db.candidates].std(0)
    query = db.features[picked] + 0.3 * rng.normal(size=(args.queries, len(spread))) * spread
    playing = np.where(rng.random(args.queries) < 0.5, picked, -1)
    same = np.array_equal(db.nearest(query, playing), db.nearest_brute(query, playing))
    tree = cpu_seconds(lambda: db.nearest(query, playing))
    brute = cpu_seconds(lambda: db.nearest_brute(query, playing))
    print(
        f"database: {len(own)} clips, {frames} frames ({frames / FPS / 60:.1f} min at 30 Hz), "
        f"{len(db.candidates)} candidates, {db.features.shape[1]} features; built in {built:.1f} s"
    )
    print(f"KD-tree and brute force return the same frames: {same}")
    print(f"{args.queries} queries: KD-tree {tree * 1e3:.2f} ms, brute force {brute * 1e3:.2f} ms")
    if not same:
        raise SystemExit("the KD-tree's matches differ from the brute force's")
    print(f"match_speedup: {brute / tree:.1f} x")


if __name__ == "__main__":
    main()
