"""How much outside help would the matched opponent need to stay up? Its falls against the still
partner with a hand on its pelvis, by the hand's stiffness, and how hard the hand pushed.

    python benchmarks/matched_assist.py FOLDER [--seconds 60]

FOLDER is a matched opponent (`ringside export --run KEY --matched`). Vid2Player3D (Zhang et al.
2023) plays its players' motion through a tracker given a residual force: a learned force on
the root that lets it follow motion its body alone cannot. Before building one, this measures
the crudest such help, not learned: each policy step a torque on the opponent's pelvis turns it
back to the lean of the frame it tracks (upright but for a walk's few degrees), ``stiffness``
(N m per radian of tilt) against the tilt and a tenth of that (N m s per radian) against the
tilt's rate, about the horizontal axes only (its turning is its own), and a force towards that
frame's pelvis, its stiffness in N per metre and a tenth of it against the pelvis's velocity.
For each hand (`HANDS`), the bout against the still partner (`tasks.opponent.spar`, standing starts,
a fall restarts it and is counted): falls a minute, the torque's mean and 95th percentile as a
share of the fighter's weight moment m g h (its mass, its pelvis's standing height: the torque
that would hold it leaning flat), the force's as a share of its weight m g, and the pelvis's
mean speed on the floor (a fighter held up but standing still is not the answer). Stiffness 0
is the opponent as it is. A hand may be capped, its force at that share of m g and its torque
at that share of m g h, as a residual force's action is bounded (how much would a learned one
need to be allowed?), and its force may be the vertical part alone (holding up, not pulling).
Last line: ``matched_assist_falls_per_min: <falls> /min`` with the last hand of `HANDS`.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.arena.env import ArenaEnv  # noqa: E402
from models.humanoid.observations import BodyState  # noqa: E402
from models.tracking.matched import MatchedTracker  # noqa: E402
from tasks.opponent.folder import load_opponent  # noqa: E402
from tasks.opponent.spar import spar  # noqa: E402


class HandSetting(NamedTuple):
    turning: float  # N m per radian of tilt
    holding: float  # N per metre of the pelvis from the motion's
    cap: float | None = None  # the force's cap as a share of m g, the torque's of m g h
    vertical: bool = False  # the force's vertical part alone: holds it up, pulls it nowhere


HANDS = (
    HandSetting(0.0, 0.0),
    HandSetting(300.0, 0.0),
    HandSetting(1000.0, 0.0),
    HandSetting(0.0, 1000.0),
    HandSetting(300.0, 1000.0),
    HandSetting(300.0, 3000.0, cap=0.1),
    HandSetting(300.0, 3000.0, cap=0.2),
    HandSetting(300.0, 3000.0, cap=0.3),
    HandSetting(300.0, 3000.0, vertical=True),
    HandSetting(300.0, 3000.0, cap=0.3, vertical=True),
    HandSetting(300.0, 3000.0),
)
GRAVITY = 9.81


class Hand:
    """The torque and force on fighter ``slot``'s pelvis that turn it back to the lean of the
    frame its ``matched`` controller tracks and move it towards that frame's pelvis (module
    docstring), and what they gave step by step."""

    def __init__(self, matched: MatchedTracker, slot: int, setting: HandSetting):
        self.matched, self.slot, self.setting = matched, slot, setting
        self.torques: list[float] = []
        self.forces: list[float] = []
        self.pelvis: list[np.ndarray] = []
        self.mass: float | None = None
        self.height: float | None = None

    def __call__(self, env: ArenaEnv, bodies: BodyState) -> np.ndarray:
        agent = env.index.agents[self.slot]
        if self.mass is None:  # at the standing start
            self.mass = float(env.model.body_mass[agent.body_ids].sum())
            self.height = float(bodies.pos[0, self.slot, 0, 2])
        at, frame = bodies.pos[0, self.slot, 0], bodies.rot[0, self.slot, 0]
        self.pelvis.append(at[:2].copy())
        motion = self.matched.reference(np.zeros(1, dtype=int))
        up = frame[:, 2]  # the pelvis's own vertical axis, in the world
        # The tilt from the motion's own (a walking pelvis leans a few degrees), as a rotation
        # vector taking it back there.
        wanted = motion.rot[0, 0][:, 2]
        axis = np.cross(up, wanted)
        tilt = np.arctan2(np.linalg.norm(axis), up @ wanted)
        back = axis / max(np.linalg.norm(axis), 1e-9) * tilt
        spin = bodies.ang_vel[0, self.slot, 0].copy()
        spin[2] = 0.0
        turning, holding, cap, vertical = self.setting
        torque = turning * back - 0.1 * turning * spin
        torque[2] = 0.0
        velocity = bodies.lin_vel[0, self.slot, 0]
        force = holding * (motion.pos[0, 0] - at) - 0.1 * holding * velocity
        if vertical:
            force[:2] = 0.0
        if cap is not None:
            weight = self.mass * GRAVITY
            force *= min(1.0, cap * weight / max(np.linalg.norm(force), 1e-9))
            torque *= min(1.0, cap * weight * self.height / max(np.linalg.norm(torque), 1e-9))
        self.torques.append(float(np.linalg.norm(torque)))
        self.forces.append(float(np.linalg.norm(force)))
        out = np.zeros((1, env.model.nbody, 6))
        out[0, agent.body_ids[0]] = np.concatenate([force, torque])
        return out

    def speed(self, hz: float) -> float:
        """The pelvis's mean speed on the floor (m/s), a restart's jump left out."""
        moved = np.linalg.norm(np.diff(np.array(self.pelvis), axis=0), axis=1)
        return float(moved[moved < 0.2].mean() * hz)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()
    opponent = load_opponent(args.folder, kind="matched")
    falls = None
    for setting in HANDS:
        # The hand reads the controller the bout plays (spar plays a fresh copy of a folder's).
        matched = opponent.controller.fresh()
        matched.fresh = lambda matched=matched: matched
        hand = Hand(matched, opponent.agent, setting)
        played = dataclasses.replace(opponent, controller=matched)
        result = spar(played, None, seconds=args.seconds, forces=hand)
        falls = result.falls[0] / (args.seconds / 60)
        torque = np.array(hand.torques) / (hand.mass * GRAVITY * hand.height)
        force = np.array(hand.forces) / (hand.mass * GRAVITY)
        turning, holding, cap, vertical = setting
        which = (" upwards only" if vertical else "") + (
            "" if cap is None else f", capped at {100 * cap:g} % of m g (h)"
        )
        print(
            f"a hand of {turning:g} N m/rad and {holding:g} N/m{which}: {falls:.1f} falls/min; "
            f"its torque {100 * torque.mean():.1f} % of m g h on average "
            f"({100 * np.percentile(torque, 95):.1f} % at the 95th percentile), its force "
            f"{100 * force.mean():.1f} % of m g ({100 * np.percentile(force, 95):.1f} %); "
            f"the pelvis moved at {hand.speed(result.policy_steps / result.simulated_s):.2f} m/s "
            "on the floor"
        )
    print(f"matched_assist_falls_per_min: {falls:.1f} /min")


if __name__ == "__main__":
    main()
