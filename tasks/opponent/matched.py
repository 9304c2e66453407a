"""The motion tracker playing the fighter's own footage, chosen as it goes by the partner-aware
motion matcher (`models.matching`), as a controller: the opponent of kind "matched" (DReCon,
Bergamin et al. 2019; Vid2Player3D, Zhang et al. 2023).

`MatchedTracker` keeps, per arena, the database frame the fighter is at and where the motion is
laid in the arena (a turn about the vertical and a move along the floor, as `ClipTracker` lays
its clip). Each policy step it tracks the laid motion's next frame and moves on to it. Every
`MatchConfig.search_every` steps, and whenever the played clip is about to end, it searches:
the query is the simulated fighter's body and its partner's, with the future of the frame it
plays. When the nearest frame is nearer than playing on (or the clip ends), that frame is played
from the next step, laid where the simulated body is and faces (so matching always continues
from where the body really is), and cross-faded in over `MatchConfig.blend_steps` steps (the
bodies' positions and velocities linearly, their rotations along the shortest arc, the PD
targets linearly). A motion that strays further than `MatchConfig.anchor_m` from the simulated
pelvis is moved back onto it.

At an episode start (`reset`) the search has no frame being played: its future is the standing
one (no move, facing ahead), and the match is laid where the fighter stands.

The folder of kind "matched" (`tasks.opponent.folder`): policy.onnx, the tracker's, input
"observation" (B, 451) float32, output "action" (B, 28); motion.npz, the database's clips as
played: "qpos" (F, 35) of the fighter on its bones, "partner_qpos" (F, 35) of the other fighter
of the footage at the same frames, "lengths" (C,) the clips' frame counts, "names" (C,), "fps";
and the matcher's settings in the manifest ("matcher", `MatchConfig.as_dict`).

Shape letters: B arenas given, F frames of the database, C clips.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import NQ
from models.humanoid.observations import BodyState, self_observation, stacked
from models.matching import MatchConfig, MotionDatabase, motion_database
from models.tracking.clips import reference_clip
from models.tracking.task import tracking_input
from tasks.errors import BadInput
from tasks.opponent.controller import Seen
from tasks.opponent.tracker import laid, laying, tracker_policy

KIND = "matched"
MOTION = "motion.npz"
FILES = ("policy.onnx", MOTION, "humanoid.xml", "arena.xml")


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


class MatchedTracker:
    """A tracker's policy playing ``database``'s frames as the matcher picks them (module
    docstring).

    Args:
        policy: (B, 451) float32 tracker observations -> (B, 28) float64 corrections, e.g. an
            exported tracker's `PolicyFile.run`.
        database: the fighter's motion, at the policy's rate, with its matcher's settings.
    """

    def __init__(
        self,
        policy: Callable[[np.ndarray], np.ndarray],
        database: MotionDatabase,
        counts: MatchCounts | None = None,
    ):
        self.policy, self.database = policy, database
        self.config = database.config
        self.counts = MatchCounts() if counts is None else counts
        self._at = np.zeros(0, dtype=int)  # by arena: the database frame it is at; -1: none
        self._turn = np.zeros((0, 3, 3))  # by arena: the motion's turn about the vertical
        self._shift = np.zeros((0, 3))  # by arena: then its move along the floor
        self._since = np.zeros(0, dtype=int)  # by arena: steps since its last search
        # By arena: the motion faded out (its frame, turn and move) and steps left of the fade.
        self._old = np.zeros(0, dtype=int)
        self._old_turn = np.zeros((0, 3, 3))
        self._old_shift = np.zeros((0, 3))
        self._fade = np.zeros(0, dtype=int)

    def fresh(self) -> MatchedTracker:
        return MatchedTracker(self.policy, self.database, self.counts)

    def _grow(self, count: int) -> None:
        extra = count - len(self._at)
        if extra <= 0:
            return
        eye = np.tile(np.eye(3), (extra, 1, 1))
        self._at = np.concatenate([self._at, np.full(extra, -1)])
        self._turn = np.concatenate([self._turn, eye])
        self._shift = np.concatenate([self._shift, np.zeros((extra, 3))])
        self._since = np.concatenate([self._since, np.zeros(extra, dtype=int)])
        self._old = np.concatenate([self._old, np.zeros(extra, dtype=int)])
        self._old_turn = np.concatenate([self._old_turn, eye])
        self._old_shift = np.concatenate([self._old_shift, np.zeros((extra, 3))])
        self._fade = np.concatenate([self._fade, np.zeros(extra, dtype=int)])

    def frames(self, arenas: np.ndarray) -> np.ndarray:
        """(B,) the database frame the fighter is at in each of ``arenas``."""
        return self._at[np.asarray(arenas, dtype=int)].copy()

    def reference(self, arenas: np.ndarray) -> BodyState:
        """(B,) the frame each fighter of ``arenas`` (B,) tracks next, laid in its arena and
        cross-faded from the motion it left."""
        ids = np.asarray(arenas, dtype=int)
        return self._next(ids)[0]

    def _next(self, ids: np.ndarray) -> tuple[BodyState, np.ndarray, np.ndarray]:
        """The next frame's laid states (B,), its o^self (B, 223) and its PD targets (B, 28)."""
        library = self.database.library
        nxt = library.next(self._at[ids])
        states = laid(library.clip.states[nxt], self._turn[ids], self._shift[ids])
        actions = library.clip.actions[nxt]
        fading = self._fade[ids] > 0
        if not fading.any():
            return states, library.clip.observation[nxt], actions
        old = library.next(self._old[ids])
        before = laid(library.clip.states[old], self._old_turn[ids], self._old_shift[ids])
        w = np.where(fading, 1.0 - self._fade[ids] / (self.config.blend_steps + 1), 1.0)
        states = cross_fade(before, states, w)
        actions = library.clip.actions[old] + w[:, None] * (actions - library.clip.actions[old])
        return states, self_observation(states), actions

    def _ending(self, at: np.ndarray) -> np.ndarray:
        """(B,) whether the clip played from frames ``at`` (B,) ends within two steps: a match
        is due, and is played whatever its distance."""
        library = self.database.library
        return library.at_end(library.next(library.next(at)))

    def _search(self, ids: np.ndarray, seen: Seen, rows: np.ndarray, *, start: bool) -> None:
        """Search for the fighters of arenas ``ids`` (rows ``rows`` of ``seen``) and play the
        match where it beats playing on (always at a ``start``)."""
        db = self.database
        body, partner = seen.body[rows], seen.bodies[rows, 1 - seen.slot]
        playing = np.full(len(ids), -1) if start else self._at[ids]
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
        self._since[ids] = 0
        if not switch.any():
            return
        ids, rows, found = ids[switch], rows[switch], found[switch]
        self.counts.switches += int(switch.sum()) if not start else 0
        if not start and self.config.blend_steps:
            self._old[ids] = self._at[ids]
            self._old_turn[ids] = self._turn[ids]
            self._old_shift[ids] = self._shift[ids]
            self._fade[ids] = self.config.blend_steps
        else:
            self._fade[ids] = 0
        # Laid where the simulated body is, at the frame before the one tracked next.
        self._turn[ids], self._shift[ids] = laying(seen.body[rows], db.library.clip.states[found])
        self._at[ids] = found

    def start_at(self, frames: np.ndarray) -> None:
        """Arenas 0 to len(``frames``) - 1 start at database ``frames``, where the footage has
        them (no search made)."""
        ids = np.arange(len(frames))
        self._grow(len(ids))
        self._at[ids], self._turn[ids], self._shift[ids] = frames, np.eye(3), 0.0
        self._since[ids], self._fade[ids] = 0, 0

    def play(self, seen: Seen) -> tuple[np.ndarray, BodyState]:
        """The motion alone, no policy: after the searches due this step, the frame each
        arena of ``seen`` plays next as qpos (B, 35) and as body states (B,)."""
        ids = self._due(seen)
        qpos, states = self._next_qpos(ids), self._next(ids)[0]
        self._advance(ids)
        return qpos, states

    def reset(self, seen: Seen) -> None:
        ids = np.asarray(seen.arenas, dtype=int)
        self._grow(int(ids.max()) + 1 if len(ids) else 0)
        if len(ids):
            self._search(ids, seen, np.arange(len(ids)), start=True)

    def _due(self, seen: Seen) -> np.ndarray:
        """The arenas of ``seen`` (checked to be reset) after the searches due this step."""
        ids = np.asarray(seen.arenas, dtype=int)
        if len(ids) and (ids.max() >= len(self._at) or (self._at[ids] < 0).any()):
            raise ValueError("act before reset: every arena's episode starts with `reset`")
        due = (self._since[ids] >= self.config.search_every) | self._ending(self._at[ids])
        if due.any():
            self._search(ids[due], seen, np.flatnonzero(due), start=False)
        return ids

    def _advance(self, ids: np.ndarray) -> None:
        """Arenas ``ids`` on to the frames just tracked."""
        library = self.database.library
        self._at[ids] = library.next(self._at[ids])
        self._old[ids] = library.next(self._old[ids])
        self._fade[ids] = np.maximum(self._fade[ids] - 1, 0)
        self._since[ids] += 1

    def act(self, seen: Seen) -> np.ndarray:
        ids = self._due(seen)
        states, observation, actions = self._next(ids)
        # The motion moved back under the simulated pelvis where it strayed: both motions of a
        # fade move alike, so the faded frame moves with them (its o^self does not change).
        sim = seen.body
        strayed = np.linalg.norm((states.pos[:, 0] - sim.pos[:, 0])[:, :2], axis=-1)
        far = strayed > self.config.anchor_m
        if far.any():
            back = sim.pos[far, 0] - states.pos[far, 0]
            back[:, 2] = 0.0
            self._shift[ids[far]] += back
            self._old_shift[ids[far]] += back
            states.pos[far] += back[:, None]
        given = tracking_input(sim, states, observation)
        correction = self.policy(np.concatenate([self_observation(sim), given], -1))
        self._advance(ids)
        return actions + correction

    def _next_qpos(self, ids: np.ndarray) -> np.ndarray:
        """(B, 35) the qpos of the frame arenas ``ids`` track next, laid as `_next` lays it and
        cross-faded in qpos (the root's position and the hinges linearly, its rotation along the
        shortest arc)."""
        library = self.database.library
        qpos = laid_qpos(
            library.clip.qpos[library.next(self._at[ids])], self._turn[ids], self._shift[ids]
        )
        fading = self._fade[ids] > 0
        if not fading.any():
            return qpos
        old = library.next(self._old[ids])
        before = laid_qpos(library.clip.qpos[old], self._old_turn[ids], self._old_shift[ids])
        w = np.where(fading, 1.0 - self._fade[ids] / (self.config.blend_steps + 1), 1.0)
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
    players = [MatchedTracker(lambda x: np.zeros((len(x), 28)), db) for db in databases]
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


def motion_file(
    clips: Sequence[tuple[str, np.ndarray, np.ndarray]], fps: float
) -> dict[str, np.ndarray]:
    """The arrays of motion.npz (module docstring) of ``clips``, each its name, the fighter's
    qpos (T, 35) and the other fighter's at the same frames (T, 35)."""
    return {
        "qpos": np.concatenate([np.asarray(q, dtype=np.float64) for _, q, _ in clips]),
        "partner_qpos": np.concatenate([np.asarray(p, dtype=np.float64) for _, _, p in clips]),
        "lengths": np.array([len(q) for _, q, _ in clips]),
        "names": np.array([name for name, _, _ in clips]),
        "fps": np.float64(fps),
    }


def motion_of(
    arrays: Mapping[str, np.ndarray],
    bones: BoneLengths,
    partner_bones: BoneLengths,
    config: MatchConfig,
) -> MotionDatabase:
    """The MotionDatabase of motion.npz's ``arrays`` (`motion_file`), the fighter on ``bones``
    and its partner on ``partner_bones``; ValueError saying what is wrong."""
    qpos, partner = np.asarray(arrays["qpos"]), np.asarray(arrays["partner_qpos"])
    lengths, names = np.asarray(arrays["lengths"]), np.asarray(arrays["names"])
    fps = float(arrays["fps"])
    if qpos.ndim != 2 or qpos.shape[1] != NQ or partner.shape != qpos.shape:
        raise ValueError(
            f"qpos and partner_qpos must both be (F, {NQ}), got {qpos.shape} and {partner.shape}"
        )
    if (
        lengths.ndim != 1
        or len(names) != len(lengths)
        or lengths.sum() != len(qpos)
        or (lengths < 2).any()
    ):
        raise ValueError(
            f"lengths {lengths.tolist()} do not cut {len(qpos)} frames into clips of 2 or more"
        )
    cuts = np.cumsum(lengths)[:-1]
    own = [
        reference_clip(str(n), q, bones, fps=fps)
        for n, q in zip(names, np.split(qpos, cuts), strict=True)
    ]
    others = [
        reference_clip(f"{n}:partner", q, partner_bones, fps=fps)
        for n, q in zip(names, np.split(partner, cuts), strict=True)
    ]
    return motion_database(own, others, fps=fps, config=config)


def load_motion(
    path: Path,
    bones: BoneLengths,
    partner_bones: BoneLengths,
    *,
    policy_hz: float,
    config: MatchConfig,
) -> MotionDatabase:
    """motion.npz as a MotionDatabase (`motion_of`); BadInput naming the file otherwise."""
    names = ("qpos", "partner_qpos", "lengths", "names", "fps")
    try:
        with np.load(path, allow_pickle=False) as stored:
            arrays = {name: stored[name] for name in names}
    except (OSError, ValueError, KeyError) as error:
        raise BadInput(str(path), f"not a motion file with {', '.join(names)} ({error})") from error
    if float(arrays["fps"]) != policy_hz:
        raise BadInput(
            str(path),
            f"motion at {float(arrays['fps']):g} fps; the policy steps at {policy_hz:g} Hz, a "
            "frame a step",
        )
    try:
        return motion_of(arrays, bones, partner_bones, config)
    except ValueError as error:
        raise BadInput(str(path), str(error)) from error


def load(
    folder: Path, manifest: dict, bones: tuple[BoneLengths, BoneLengths], agent: int
) -> MatchedTracker:
    """The controller of a "matched" folder (files checked by the caller)."""
    policy, policy_hz = tracker_policy(folder, manifest)
    try:
        config = MatchConfig.from_dict(manifest["matcher"])
    except (KeyError, TypeError, ValueError) as error:
        raise BadInput(
            str(folder / "manifest.json"), f"matcher settings unreadable ({error})"
        ) from error
    database = load_motion(
        folder / MOTION, bones[agent], bones[1 - agent], policy_hz=policy_hz, config=config
    )
    return MatchedTracker(policy.run, database)
