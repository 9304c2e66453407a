"""The still guard: a fighter holding a pose, whatever it sees.

The baseline a trained policy must beat to show it moves like the adversary rather than merely
stays up, and `spar`'s simplest scripted partner: every PD target at ``hinges`` (28,), e.g. its
guard (`ReferenceMotions.stance`, a pose it holds unaided).
"""

from __future__ import annotations

import numpy as np

from models.arena.controller import Seen
from models.humanoid.kinematics import NUM_ACTUATED, joint_targets_to_action


class StillGuard:
    """Holds ``hinges`` (28,) hinge angles (module docstring)."""

    def __init__(self, hinges: np.ndarray):
        hinges = np.asarray(hinges, dtype=np.float64)
        if hinges.shape != (NUM_ACTUATED,) or not np.isfinite(hinges).all():
            raise ValueError(
                f"hinges must be finite with shape ({NUM_ACTUATED},), got {hinges.shape}"
            )
        self.hinges = hinges
        self.action = joint_targets_to_action(hinges)

    def reset(self, seen: Seen) -> None:
        pass

    def act(self, seen: Seen) -> np.ndarray:
        return np.broadcast_to(self.action, (len(seen.arenas), NUM_ACTUATED)).copy()

    def fresh(self) -> StillGuard:
        return self
