"""Does the matched opponent stay up? Its falls against the still partner, by matcher settings,
beside its tracker replaying each of its clips once.

    python benchmarks/matched_falls.py FOLDER [--seconds 60]

FOLDER is a matched opponent (`ringside export --run KEY --matched`). Each variant of its matcher's
settings (the folder's own; no cross-fade; a search every 0.5 s; a search only at a clip's end;
no anchoring) spars ``--seconds`` against the still partner (`tasks.opponent.spar`, standing
starts, a fall restarts the bout and is counted), and the number of searches that changed the
frame played is counted. Beside them, the baseline without transitions: the same tracker playing
each clip of the folder's footage once (`ClipTracker`, started at rest in its first pose), its
falls over the clip. Last line: ``matched_falls_per_min: <falls> /min`` for the folder's own
settings.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.tracking.clips import reference_clip  # noqa: E402
from models.tracking.matched import MatchedTracker  # noqa: E402
from tasks.opponent.folder import load_opponent  # noqa: E402
from tasks.opponent.spar import spar  # noqa: E402
from tasks.opponent.tracker import ClipTracker  # noqa: E402

VARIANTS = {
    "the folder's settings": {},
    "no cross-fade": {"blend_steps": 0},
    "a search every 0.5 s": {"search_every": 15},
    "a search only at a clip's end": {"search_every": 1_000_000},
    "no anchoring": {"anchor_m": 1e6},
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()
    base = load_opponent(args.folder)
    if not isinstance(base.controller, MatchedTracker):
        raise SystemExit(f"{args.folder}: a folder of kind {base.kind!r}, not 'matched'")
    db = base.controller.database
    minutes = args.seconds / 60
    own = None
    for name, change in VARIANTS.items():
        config = dataclasses.replace(db.config, **change)
        matched = MatchedTracker(base.controller.policy, dataclasses.replace(db, config=config))
        result = spar(dataclasses.replace(base, controller=matched), None, seconds=args.seconds)
        rate = result.falls[0] / minutes
        own = rate if own is None else own
        print(
            f"{name}: {rate:.1f} falls/min; {matched.counts.switches} of "
            f"{matched.counts.searches} searches "
            "changed the frame played"
        )
    lib = db.library
    falls, seconds = [], []
    for c in range(lib.num_clips):
        qpos = lib.clip.qpos[lib.start[c] : lib.last[c] + 1]
        clip = reference_clip(f"clip {c}", qpos, base.bones[base.agent], fps=lib.fps)
        guard = base.guard.copy()
        guard[base.agent] = qpos[0, 7:]
        replay = dataclasses.replace(
            base, controller=ClipTracker(base.controller.policy, clip), guard=guard
        )
        result = spar(replay, None, seconds=(len(qpos) - 1) / lib.fps)
        falls.append(result.falls[0])
        seconds.append((len(qpos) - 1) / lib.fps)
    falls, seconds = np.array(falls), np.array(seconds)
    print(
        f"the tracker replaying each of the {lib.num_clips} clips once from rest: "
        f"{(falls > 0).sum()} fell; {falls.sum() / (seconds.sum() / 60):.1f} falls/min over "
        f"{seconds.sum():.0f} s"
    )
    print(f"matched_falls_per_min: {own:.1f} /min")


if __name__ == "__main__":
    main()
