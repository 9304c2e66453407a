"""The tracker playing a fighter's own motion as the partner-aware motion matcher picks it
(`models.tracking.matching`; DReCon, Bergamin et al. 2019; Vid2Player3D, Zhang et al. 2023):
the matched opponent's controller, and the reference a tracker trains on in bouts
(`models.tracking.bouts`).

`MatchedTracker` keeps, per arena, the database frame the fighter is at and where the motion is
laid in the arena (a turn about the vertical and a move along the floor, `laying`). Each policy
step it tracks the laid motion's next frame and moves on to it. Every
`MatchConfig.search_every` steps, and whenever the played clip is about to end, it searches:
the query is the simulated fighter's body and its partner's, with the future of the frame it
plays. When the nearest frame is nearer than playing on (or the clip ends), that frame is played
from the next step, laid where the simulated body is and faces (so matching always continues
from where the body really is), and cross-faded in over `MatchConfig.blend_steps` steps (the
bodies' positions and velocities linearly, their rotations along the shortest arc, the PD
targets linearly). A motion that strays further than `MatchConfig.anchor_m` from the simulated
pelvis is moved back onto it.

At an episode start (`reset`) the search has no frame being played: its future is the standing
one (no move, facing ahead), and the match is laid where the fighter stands; over the first
`MatchConfig.ease_steps` steps the reference is faded in from the body as it stood at the start,
held still (its PD targets are the match's throughout: the body's own are not seen). Measured
on a tracker near its gate (docs/opponent.md): with the footage's walk asked for at once, the
fighter fell 42 times a minute from its standing start; faded in over 15, 30 and 60 steps, 28,
18 and 32.

`target` and `advance` are the two halves of a step (the reference and its PD targets, then the
move on to the next frame), for a caller that runs the policy itself (training); `act` is both
with the policy between them.

Shape letters: B arenas given, F frames of the database.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from models.arena.controller import Seen
from models.humanoid.kinematics import NQ, heading_frame_of_matrix
from models.humanoid.observations import BodyState, self_observation, stacked
from models.tracking.matching import MotionDatabase
from models.tracking.task import tracking_input


def laid(states: BodyState, turn: np.ndarray, shift: np.ndarray) -> BodyState:
    """States (B,) turned by ``turn`` (B, 3, 3) about the vertical and moved by ``shift`` (B, 3)."""
    return BodyState(
        np.einsum("nij,nbj->nbi", turn, states.pos) + shift[:, None],
        turn[:, None] @ states.rot,
        np.einsum("nij,nbj->nbi", turn, states.lin_vel),
        np.einsum("nij,nbj->nbi", turn, states.ang_vel),
    )


def laying(body: BodyState, frame: BodyState) -> tuple[np.ndarray, np.ndarray]:
    """The turn (B, 3, 3) and move (B, 3) that lay motion frames ``frame`` (B,) on simulated
    bodies ``body`` (B,): the frame's pelvis on the body's on the floor, facing its way."""
    turn = heading_frame_of_matrix(body.rot[:, 0]) @ heading_frame_of_matrix(
        frame.rot[:, 0]
    ).swapaxes(-1, -2)
    shift = body.pos[:, 0] - np.einsum("nij,nj->ni", turn, frame.pos[:, 0])
    shift[:, 2] = 0.0
    return turn, shift


def cross_fade(a: BodyState, b: BodyState, w: np.ndarray) -> BodyState:
    """States (B,) a fraction ``w`` (B,) of the way from ``a`` to ``b``: positions and velocities
    linearly, rotations along the shortest arc."""
    lin = w[:, None, None]
    rel = Rotation.from_matrix((a.rot.swapaxes(-1, -2) @ b.rot).reshape(-1, 3, 3)).as_rotvec()
    step = Rotation.from_rotvec(rel * np.repeat(w, a.rot.shape[1])[:, None]).as_matrix()
    return BodyState(
        a.pos + lin * (b.pos - a.pos),
        a.rot @ step.reshape(a.rot.shape),
        a.lin_vel + lin * (b.lin_vel - a.lin_vel),
        a.ang_vel + lin * (b.ang_vel - a.ang_vel),
    )


@dataclass
class MatchCounts:
    """Searches made and how many of them changed the frame played (an episode's first match
    not counted), by a controller and its `fresh` copies together."""

    searches: int = 0
    switches: int = 0


@dataclass(frozen=True, eq=False)
class Target:
    """What a fighter tracks at one step (`MatchedTracker.target`), for B arenas.

    Attributes:
        states: (B,) the reference frame laid in the arena (faded, eased in, anchored).
        given: (B, 228) the policy's input of it (`tracking_input`).
        actions: (B, 28) its PD targets, to which the policy's correction is added.
    """

    states: BodyState
    given: np.ndarray
    actions: np.ndarray


# Per arena (the rows of each array): the database frame it is at (-1: none yet), the motion's
# turn about the vertical and its move along the floor, steps since the last search; the motion
# being faded out (its frame, turn and move) and the steps left of that fade; the body as it
# stood at the episode's start (pelvis and bodies' positions and rotations) and the steps left
# of the ease-in from it.
_PER_ARENA = {
    "at": ((), -1),
    "turn": ((3, 3), None),
    "shift": ((3,), 0.0),
    "since": ((), 0),
    "old": ((), 0),
    "old_turn": ((3, 3), None),
    "old_shift": ((3,), 0.0),
    "fade": ((), 0),
    "held_pos": ((15, 3), 0.0),
    "held_rot": ((15, 3, 3), None),
    "ease": ((), 0),
}


class MatchedTracker:
    """A tracker's policy playing ``database``'s frames as the matcher picks them (module
    docstring).

    Args:
        policy: (B, 451) float32 tracker observations -> (B, 28) float64 corrections, e.g. an
            exported tracker's `PolicyFile.run`; None for a caller that runs the policy itself
            (`target`, `advance`).
        database: the fighter's motion, at the policy's rate, with its matcher's settings.
    """

    def __init__(
        self,
        policy: Callable[[np.ndarray], np.ndarray] | None,
        database: MotionDatabase,
        counts: MatchCounts | None = None,
    ):
        self.policy, self.database = policy, database
        self.config = database.config
        self.counts = MatchCounts() if counts is None else counts
        self._s = {
            name: np.zeros((0, *shape), dtype=int if isinstance(fill, int) else float)
            for name, (shape, fill) in _PER_ARENA.items()
        }

    def fresh(self) -> MatchedTracker:
        return MatchedTracker(self.policy, self.database, self.counts)

    def state(self) -> dict[str, np.ndarray]:
        """Every arena's episode as it stands (a training checkpoint keeps it)."""
        return {name: value.copy() for name, value in self._s.items()}

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        self._s = {name: np.array(state[name]) for name in _PER_ARENA}

    def _grow(self, count: int) -> None:
        extra = count - len(self._s["at"])
        if extra <= 0:
            return
        for name, (shape, fill) in _PER_ARENA.items():
            if fill is None:  # a rotation: the identity
                more = np.broadcast_to(np.eye(3), (extra, *shape))
            else:
                more = np.full((extra, *shape), fill, dtype=self._s[name].dtype)
            self._s[name] = np.concatenate([self._s[name], more])

    def frames(self, arenas: np.ndarray) -> np.ndarray:
        """(B,) the database frame the fighter is at in each of ``arenas``."""
        return self._s["at"][np.asarray(arenas, dtype=int)].copy()

    def reference(self, arenas: np.ndarray) -> BodyState:
        """(B,) the frame each fighter of ``arenas`` (B,) tracks next, laid in its arena,
        cross-faded from the motion it left and eased in from its start."""
        ids = np.asarray(arenas, dtype=int)
        return self._next(ids)[0]

    def _next(self, ids: np.ndarray) -> tuple[BodyState, np.ndarray, np.ndarray]:
        """The next frame's laid states (B,), its o^self (B, 223) and its PD targets (B, 28)."""
        s, library = self._s, self.database.library
        nxt = library.next(s["at"][ids])
        states = laid(library.clip.states[nxt], s["turn"][ids], s["shift"][ids])
        actions = library.clip.actions[nxt]
        fading, easing = s["fade"][ids] > 0, s["ease"][ids] > 0
        if not (fading.any() or easing.any()):
            return states, library.clip.observation[nxt], actions
        if fading.any():
            old = library.next(s["old"][ids])
            before = laid(library.clip.states[old], s["old_turn"][ids], s["old_shift"][ids])
            w = np.where(fading, 1.0 - s["fade"][ids] / (self.config.blend_steps + 1), 1.0)
            states = cross_fade(before, states, w)
            actions = library.clip.actions[old] + w[:, None] * (actions - library.clip.actions[old])
        if easing.any():
            still = np.zeros_like(states.lin_vel)
            held = BodyState(s["held_pos"][ids], s["held_rot"][ids], still, still)
            w = np.where(easing, 1.0 - s["ease"][ids] / (self.config.ease_steps + 1), 1.0)
            states = cross_fade(held, states, w)
        return states, self_observation(states), actions

    def _ending(self, at: np.ndarray) -> np.ndarray:
        """(B,) whether the clip played from frames ``at`` (B,) ends within two steps: a match
        is due, and is played whatever its distance."""
        library = self.database.library
        return library.at_end(library.next(library.next(at)))

    def _search(self, ids: np.ndarray, seen: Seen, rows: np.ndarray, *, start: bool) -> None:
        """Search for the fighters of arenas ``ids`` (rows ``rows`` of ``seen``) and play the
        match where it beats playing on (always at a ``start``)."""
        s, db = self._s, self.database
        body, partner = seen.body[rows], seen.bodies[rows, 1 - seen.slot]
        playing = np.full(len(ids), -1) if start else s["at"][ids]
        query = db.query(body, partner, None if start else playing)
        found = db.nearest(query, playing)
        self.counts.searches += len(ids)
        if start:
            switch = np.ones(len(ids), dtype=bool)
        else:
            onward = db.library.next(playing)
            switch = self._ending(playing) | (
                db.distance(query, found) < db.distance(query, onward)
            )
        s["since"][ids] = 0
        if not switch.any():
            return
        ids, rows, found = ids[switch], rows[switch], found[switch]
        self.counts.switches += int(switch.sum()) if not start else 0
        if not start and self.config.blend_steps:
            s["old"][ids], s["old_turn"][ids] = s["at"][ids], s["turn"][ids]
            s["old_shift"][ids], s["fade"][ids] = s["shift"][ids], self.config.blend_steps
        else:
            s["fade"][ids] = 0
        # Laid where the simulated body is, at the frame before the one tracked next.
        s["turn"][ids], s["shift"][ids] = laying(seen.body[rows], db.library.clip.states[found])
        s["at"][ids] = found

    def start_at(self, frames: np.ndarray) -> None:
        """Arenas 0 to len(``frames``) - 1 start at database ``frames``, where the footage has
        them (no search made, no ease-in)."""
        ids = np.arange(len(frames))
        self._grow(len(ids))
        s = self._s
        s["at"][ids], s["turn"][ids], s["shift"][ids] = frames, np.eye(3), 0.0
        s["since"][ids], s["fade"][ids], s["ease"][ids] = 0, 0, 0

    def play(self, seen: Seen) -> tuple[np.ndarray, BodyState]:
        """The motion alone, no policy: after the searches due this step, the frame each
        arena of ``seen`` plays next as qpos (B, 35) and as body states (B,)."""
        ids = self._due(seen)
        qpos, states = self._next_qpos(ids), self._next(ids)[0]
        self.advance(ids)
        return qpos, states

    def reset(self, seen: Seen) -> None:
        ids = np.asarray(seen.arenas, dtype=int)
        self._grow(int(ids.max()) + 1 if len(ids) else 0)
        if len(ids):
            self._search(ids, seen, np.arange(len(ids)), start=True)
            s = self._s
            s["held_pos"][ids], s["held_rot"][ids] = seen.body.pos, seen.body.rot
            s["ease"][ids] = self.config.ease_steps

    def _due(self, seen: Seen) -> np.ndarray:
        """The arenas of ``seen`` (checked to be reset) after the searches due this step."""
        s = self._s
        ids = np.asarray(seen.arenas, dtype=int)
        if len(ids) and (ids.max() >= len(s["at"]) or (s["at"][ids] < 0).any()):
            raise ValueError("act before reset: every arena's episode starts with `reset`")
        due = (s["since"][ids] >= self.config.search_every) | self._ending(s["at"][ids])
        if due.any():
            self._search(ids[due], seen, np.flatnonzero(due), start=False)
        return ids

    def advance(self, arenas: np.ndarray) -> None:
        """Arenas ``arenas`` on to the frames just tracked."""
        s, library = self._s, self.database.library
        ids = np.asarray(arenas, dtype=int)
        s["at"][ids] = library.next(s["at"][ids])
        s["old"][ids] = library.next(s["old"][ids])
        s["fade"][ids] = np.maximum(s["fade"][ids] - 1, 0)
        s["ease"][ids] = np.maximum(s["ease"][ids] - 1, 0)
        s["since"][ids] += 1

    def target(self, seen: Seen) -> Target:
        """After the searches due this step, the frame each fighter of ``seen`` tracks next:
        moved back under the simulated pelvis where it strayed (`MatchConfig.anchor_m`)."""
        s = self._s
        ids = self._due(seen)
        states, observation, actions = self._next(ids)
        # Both motions of a fade, and the pose eased in from, move alike, so the faded frame
        # moves with them (its o^self does not change).
        sim = seen.body
        strayed = np.linalg.norm((states.pos[:, 0] - sim.pos[:, 0])[:, :2], axis=-1)
        far = strayed > self.config.anchor_m
        if far.any():
            back = sim.pos[far, 0] - states.pos[far, 0]
            back[:, 2] = 0.0
            s["shift"][ids[far]] += back
            s["old_shift"][ids[far]] += back
            s["held_pos"][ids[far]] += back[:, None]
            states.pos[far] += back[:, None]
        return Target(states, tracking_input(sim, states, observation), actions)

    def act(self, seen: Seen) -> np.ndarray:
        if self.policy is None:
            raise ValueError("a MatchedTracker without a policy has no actions of its own")
        aim = self.target(seen)
        correction = self.policy(np.concatenate([self_observation(seen.body), aim.given], -1))
        self.advance(seen.arenas)
        return aim.actions + correction

    def _next_qpos(self, ids: np.ndarray) -> np.ndarray:
        """(B, 35) the qpos of the frame arenas ``ids`` track next, laid as `_next` lays it and
        cross-faded in qpos (the root's position and the hinges linearly, its rotation along the
        shortest arc); not eased in (`play` starts where the footage has the fighter)."""
        s, library = self._s, self.database.library
        qpos = laid_qpos(
            library.clip.qpos[library.next(s["at"][ids])], s["turn"][ids], s["shift"][ids]
        )
        fading = s["fade"][ids] > 0
        if not fading.any():
            return qpos
        old = library.next(s["old"][ids])
        before = laid_qpos(library.clip.qpos[old], s["old_turn"][ids], s["old_shift"][ids])
        w = np.where(fading, 1.0 - s["fade"][ids] / (self.config.blend_steps + 1), 1.0)
        faded = before + w[:, None] * (qpos - before)
        a, b = (Rotation.from_quat(q[:, 3:7], scalar_first=True) for q in (before, qpos))
        step = Rotation.from_rotvec((a.inv() * b).as_rotvec() * w[:, None])
        faded[:, 3:7] = (a * step).as_quat(scalar_first=True)
        return faded


def laid_qpos(qpos: np.ndarray, turn: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """qpos (B, 35) turned by ``turn`` (B, 3, 3) about the vertical and moved by ``shift`` (B,
    3), as `laid` lays their body states."""
    out = qpos.copy()
    out[:, :3] = np.einsum("nij,nj->ni", turn, qpos[:, :3]) + shift
    root = Rotation.from_matrix(turn) * Rotation.from_quat(qpos[:, 3:7], scalar_first=True)
    out[:, 3:7] = root.as_quat(scalar_first=True)
    return out


def matched_streams(
    databases: tuple[MotionDatabase, MotionDatabase],
    *,
    count: int,
    frames: int,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """``count`` streams of ``frames`` frames each of the two fighters' motion as their matchers
    play it against each other, with nothing but the motion itself in the loop (DReCon trains
    its tracker on such streams: the transitions are what the tracker must learn to survive).
    Returns each fighter's qpos (count, frames, 35).

    ``databases`` are the two fighters' of one footage, frame for frame (fighter 0's clips
    with fighter 1's as its partner, and fighter 1's with fighter 0's). Each stream starts at a
    frame drawn uniformly from the candidates, both fighters where the footage has them; each
    step each fighter's matcher searches as `MatchedTracker` does, its own body the frame it
    played and its partner the other fighter's."""
    if not np.array_equal(databases[0].library.last, databases[1].library.last):
        raise ValueError("the two fighters' databases must be one footage's, clip for clip")
    ids = np.arange(count)
    players = [MatchedTracker(None, db) for db in databases]
    start = databases[0].candidates[rng.integers(len(databases[0].candidates), size=count)]
    for player in players:
        player.start_at(start)
    bodies = [player.database.library.clip.states[start] for player in players]
    qpos = np.empty((2, count, frames, NQ))
    for t in range(frames):
        both = stacked(bodies)
        seen = [
            Seen(ids, slot, both, np.zeros((count, 0)), np.zeros((count, 0))) for slot in (0, 1)
        ]
        for slot, player in enumerate(players):
            qpos[slot, :, t], bodies[slot] = player.play(seen[slot])
    return qpos[0], qpos[1]
