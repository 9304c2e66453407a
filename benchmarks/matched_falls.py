"""Does the matched opponent stay up? Its falls against the still partner, by matcher settings,
beside its tracker replaying each of its clips once.

    python benchmarks/matched_falls.py FOLDER [--seconds 60] [--partner FOLDER --bouts 10]
        [--variants NAME ...]

FOLDER is a matched opponent (`ringside export --run KEY --matched`). Each variant of its matcher's
settings (`VARIANTS`: the folder's own; no cross-fade; a search every step, every 0.5 s, only at a
clip's end; no anchoring; no ease-in at the start; a shorter future, which lets more of each clip's
frames be found; the partner's bearing weighed more), its database rebuilt with them, spars
``--seconds`` against the still partner (`tasks.opponent.spar`, standing starts, a fall restarts
the bout and is counted), and the number of searches that changed the frame played is counted.
Beside them, the baseline without transitions: the same tracker playing each clip of the
folder's footage once (`ClipTracker`, started at rest in its first pose), its falls over the
clip. Against the still partner every
restart is the same standing start, so the bout is one trajectory played again after each fall.

With ``--partner FOLDER`` (the run's other fighter, `ringside export --run KEY --matched --agent
opponent`), both fighters matched: ``--bouts`` bouts of ``--seconds`` each from standing starts,
each bout's two fighters placed where the footage has them at a frame drawn from the folder's
motion (their distance and bearings as filmed), both in their guards at rest, run side by side
by the evaluation's `simulate` (a bout ends at its first fall). Each fighter's falls per minute
and the share of bouts without a fall. Last line: ``matched_falls_per_min: <falls> /min``, the
first variant sparred (by default the folder's own settings) against the still partner.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.arena.starts import ReferenceMotions  # noqa: E402
from models.humanoid.kinematics import NV  # noqa: E402
from models.tracking.clips import reference_clip  # noqa: E402
from models.tracking.matched import MatchedTracker  # noqa: E402
from tasks.evaluate.bouts import simulate  # noqa: E402
from tasks.opponent.folder import Opponent, load_opponent  # noqa: E402
from tasks.opponent.matched import MOTION, motion_of  # noqa: E402
from tasks.opponent.spar import env_config, fighters, spar  # noqa: E402
from tasks.opponent.tracker import ClipTracker  # noqa: E402

VARIANTS = {
    "the folder's settings": {},
    "no cross-fade": {"blend_steps": 0},
    "a search every step": {"search_every": 1},
    "a search every 0.5 s": {"search_every": 15},
    "a search only at a clip's end": {"search_every": 1_000_000},
    "no anchoring": {"anchor_m": 1e6},
    "no ease-in at the start": {"ease_steps": 0},
    "a future of 0.6 s (more candidates)": {"future_s": (0.2, 0.4, 0.6)},
    "the partner's bearing weighed 3": {"weights": {"partner_bearing": 3.0}},
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--partner", type=Path, help="the other fighter's matched folder")
    parser.add_argument("--bouts", type=int, default=10)
    parser.add_argument(
        "--variants",
        nargs="+",
        choices=list(VARIANTS),
        default=list(VARIANTS),
        metavar="NAME",
        help="the matcher's variants to spar (default: all; the first is the headline)",
    )
    args = parser.parse_args()
    base = load_opponent(args.folder, kind="matched")
    db = base.controller.database
    minutes = args.seconds / 60
    own = None
    with np.load(args.folder / MOTION) as stored:
        arrays = {name: stored[name] for name in stored.files}
    for name in args.variants:
        change = dict(VARIANTS[name])
        weights = dataclasses.replace(db.config.weights, **change.pop("weights", {}))
        config = dataclasses.replace(db.config, weights=weights, **change)
        # Rebuilt: a future or a weight changes the features, the candidates and the tree.
        motion = motion_of(arrays, base.bones[base.agent], base.bones[1 - base.agent], config)
        matched = MatchedTracker(base.controller.policy, motion)
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
    if args.partner is not None:
        partner = load_opponent(args.partner)
        both_matched(base, partner, arrays, bouts=args.bouts, seconds=args.seconds)
    print(f"matched_falls_per_min: {own:.1f} /min")


def both_matched(
    base: Opponent, partner: Opponent, arrays: dict, *, bouts: int, seconds: float
) -> None:
    """Both fighters matched, ``bouts`` bouts from standing starts where the footage has them
    (module docstring; ``arrays``: the folder's motion.npz)."""
    (mine, theirs), bones, guards = fighters(base, partner)
    motion = base.controller.database
    frames = motion.candidates
    qpos, other = arrays["qpos"][frames], arrays["partner_qpos"][frames]
    slot = base.agent
    by_slot = (qpos, other) if slot == 0 else (other, qpos)
    zero = np.zeros((len(frames), NV))
    start = ReferenceMotions(by_slot[0], zero, by_slot[1], zero, stance=guards)
    controllers = (mine, theirs) if slot == 0 else (theirs, mine)
    config = env_config(base)
    steps = round(seconds * config.policy_hz)
    played = simulate(
        controllers,
        reference=start,
        bones=(bones[0], bones[1]),
        env_config=config,
        episodes=bouts,
        frames=steps,
        seed=0,
    )
    for who, agent in (("the opponent", slot), ("its matched partner", 1 - slot)):
        fell = played.fell[:, agent]
        print(
            f"both matched, {bouts} bouts of {seconds:g} s from standing starts: {who} fell "
            f"{fell.sum() / played.minutes:.1f} times a minute; {(~played.fell.any(1)).sum()} of "
            f"{bouts} bouts without a fall; "
            f"bouts of {played.steps.mean() / played.policy_hz:.1f} s on average"
        )


if __name__ == "__main__":
    main()
