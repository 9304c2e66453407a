"""The controller interface: what picks a fighter's actions each policy step.

Everything that puts a fighter in an arena (the evaluation's bouts, `spar`, the live bout of
`spar-server` and its viewer) hands its controller the same thing each policy step, `Seen`,
and takes back the fighter's actions: MAAIP's actions (§4.2), the PD targets of its 28 hinges
as exponential maps for the 3-DoF joints and angles for elbows and knees. At every episode
start (a reset of the arena, or of the fighter alone) it calls `reset` first, with what the
fighter sees of its start. A bout of its own (a live session) takes its controller's `fresh`
copy. The kinds (`tasks.opponent.maaip`, `.still`, `.tracker`, `.matched`) differ only
in what they read of `Seen` and in what they keep between steps. The interface lives with the
arena, not with the opponent folders, because training plays a controller too (a tracker in
bouts, `models.tracking.bouts`).

Shape letters: B arenas given (the rows), 2 fighters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from models.humanoid.observations import BodyState


@dataclass(frozen=True, eq=False)
class Seen:
    """What the arena gives one fighter's controller for B arenas at one policy step.

    Attributes:
        arenas: (B,) which arenas the rows are (indices into the caller's batch, stable across
            an episode: a controller that keeps something per episode keys it by them).
        slot: the fighter's slot in the arena (0 or 1); its partner is ``1 - slot``.
        bodies: (B, 2) both fighters' body states (slot 0's, then slot 1's), as the arena's
            step or start left them.
        observation: (B, 274) the fighter's observation [o^self, o^opp] (MAAIP §4.2).
        partner_observation: (B, 274) its partner's.
        task: (B, 2) the fighter's heading task input (MAAIP §5.4), or None without a task.
    """

    arenas: np.ndarray
    slot: int
    bodies: BodyState
    observation: np.ndarray
    partner_observation: np.ndarray
    task: np.ndarray | None = None

    @property
    def body(self) -> BodyState:
        """(B,) the fighter's own body states."""
        return self.bodies[:, self.slot]


class Controller(Protocol):
    """Picks a fighter's actions from what it sees (module docstring)."""

    def reset(self, seen: Seen) -> None:
        """Episodes start in arenas ``seen.arenas``, the fighter as ``seen`` shows it."""
        ...

    def act(self, seen: Seen) -> np.ndarray:
        """(B, 28) float64 actions for the rows of ``seen``."""
        ...

    def fresh(self) -> Controller:
        """The same controller keeping nothing of this one's episodes, for a bout of its own
        (the live server runs sessions side by side, each with its arena 0); a controller that
        keeps nothing between steps is its own."""
        ...
