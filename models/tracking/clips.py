"""The clip library: reference clips on a humanoid, and which frame of which clip is where.

A tracker's reference motion is every clip of one humanoid end to end, F frames in all; a frame
is named by its flat index into them (`ClipLibrary`), as MimicKit's motion library names a
motion frame by a motion id and a time (`calc_motion_frame(ids, times)`). The library answers
which clip and frame a flat index is (`ClipLibrary.locate`), which flat index a clip's frame or
time is (`ClipLibrary.index`, `ClipLibrary.frame`), which frame follows (`ClipLibrary.next`) and
where a clip ends; every per-frame field of the joined clip (`ClipLibrary.clip`: qpos, body
states, o^self, centre of mass, actions) is indexed by it. Frames are not blended: a time names
its nearest frame.

Shape letters: T frames of a clip, F frames of all clips, C clips.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from models.arena.mjcf import NUM_AGENTS
from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.compiled import body_states, humanoid_index, velocities
from models.humanoid.kinematics import NQ, joint_targets_to_action
from models.humanoid.observations import BodyState, self_observation
from models.tracking.reward import centre_of_mass


@dataclass(frozen=True, eq=False)
class ReferenceClip:
    """One clip on one humanoid, per frame, on the policy's grid.

    Attributes:
        name: the clip's name.
        qpos: (T, 35) the humanoid's qpos.
        qvel: (T, 34) by central differences (`models.humanoid.compiled.velocities`).
        states: BodyState (T,) of the frames.
        observation: (T, 223) o^self of each frame.
        com: (T, 3) the centre of mass.
        actions: (T, 28) each frame's hinge angles as MAAIP actions (the PD targets that hold it).
        body_mass: (15,) the bodies' masses (kg), for `centre_of_mass`.
        body_com: (15, 3) each body's centre of mass in its own frame (m).
    """

    name: str
    qpos: np.ndarray
    qvel: np.ndarray
    states: BodyState
    observation: np.ndarray
    com: np.ndarray
    actions: np.ndarray
    body_mass: np.ndarray
    body_com: np.ndarray

    @property
    def num_frames(self) -> int:
        return len(self.qpos)


def reference_clip(name: str, qpos: np.ndarray, bones: BoneLengths, *, fps: float) -> ReferenceClip:
    """A clip of qpos (T, 35) at ``fps`` on the humanoid with ``bones``, ready to track.

    Raises:
        ValueError: naming the clip, if it has fewer than 2 frames or is not finite.
    """
    q = np.asarray(qpos, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != NQ or len(q) < 2 or not np.isfinite(q).all():
        raise ValueError(f"clip {name!r}: qpos must be finite, (T >= 2, {NQ}), got {q.shape}")
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(bones))
    index = humanoid_index(model)
    qvel = velocities(model, q, fps)
    states = body_states(model, q, qvel, index)
    mass = model.body_mass[index.body_ids].copy()
    local = model.body_ipos[index.body_ids].copy()
    return ReferenceClip(
        name=name,
        qpos=q,
        qvel=qvel,
        states=states,
        observation=self_observation(states),
        com=centre_of_mass(states, mass, local),
        actions=joint_targets_to_action(q[:, 7:]),
        body_mass=mass,
        body_com=local,
    )


@dataclass(frozen=True, eq=False)
class TrackingData:
    """What a tracker trains on: each agent's clips on its own humanoid.

    Attributes:
        key: names the data (a dataset's key, or e.g. "clips:walk,punch").
        bones: agent 0's and agent 1's bone lengths.
        clips: agent 0's clips and agent 1's (`reference_clip` on that agent's bones).
        fps: the clips' frame rate, which must be the policy's (`EnvConfig.policy_hz`).
    """

    key: str
    bones: tuple[BoneLengths, BoneLengths]
    clips: tuple[tuple[ReferenceClip, ...], tuple[ReferenceClip, ...]]
    fps: float


def tracking_data(
    clips: tuple[Mapping[str, np.ndarray], Mapping[str, np.ndarray]],
    bones: tuple[BoneLengths, BoneLengths],
    *,
    fps: float,
    key: str,
) -> TrackingData:
    """TrackingData from each agent's clips as qpos arrays by name (retargeted onto its bones)."""
    if len(clips) != NUM_AGENTS or not all(clips):
        raise ValueError("clips must hold one non-empty mapping of clips per agent")
    made = tuple(
        tuple(reference_clip(name, q, bones[a], fps=fps) for name, q in clips[a].items())
        for a in range(NUM_AGENTS)
    )
    return TrackingData(key, bones, made, float(fps))  # type: ignore[arg-type]


@dataclass(frozen=True, eq=False)
class ClipLibrary:
    """One humanoid's clips end to end (F frames), and where each clip starts and ends.

    Attributes:
        clip: the clips joined, one `ReferenceClip` of F frames (its body masses the first
            clip's: the clips are one humanoid's); a flat index picks a frame of any field.
        start: (C,) the flat index of each clip's first frame.
        last: (C,) the flat index of each clip's last frame.
        startable: the flat indices of every frame but the clips' last (reference state
            initialisation starts there: each has a next frame).
        fps: the clips' frame rate.
    """

    clip: ReferenceClip
    start: np.ndarray
    last: np.ndarray
    startable: np.ndarray
    fps: float

    @property
    def num_clips(self) -> int:
        return len(self.start)

    def index(self, ids: np.ndarray, frames: np.ndarray) -> np.ndarray:
        """(...) the flat index of frame ``frames`` (...) of clip ``ids`` (...).

        Raises:
            ValueError: a clip id or a frame outside its clip.
        """
        ids, frames = np.asarray(ids), np.asarray(frames)
        if ids.size and (ids.min() < 0 or ids.max() >= self.num_clips):
            raise ValueError(f"ids must be clip indices in [0, {self.num_clips}), got {ids}")
        lengths = self.last[ids] - self.start[ids] + 1
        if ((frames < 0) | (frames >= lengths)).any():
            raise ValueError(f"frames must lie in their clips (lengths {lengths}), got {frames}")
        return self.start[ids] + frames

    def frame(self, ids: np.ndarray, times: np.ndarray) -> np.ndarray:
        """(...) the flat index of the frame of clip ``ids`` (...) nearest to ``times`` (...,
        seconds from the clip's first frame), held at the clip's ends."""
        ids = np.asarray(ids)
        frames = np.rint(np.asarray(times, dtype=float) * self.fps).astype(int)
        return self.start[ids] + np.clip(frames, 0, self.last[ids] - self.start[ids])

    def locate(self, flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The clip (...) and the frame in it (...) of each flat index ``flat`` (...)."""
        clip = np.searchsorted(self.start, flat, side="right") - 1
        return clip, flat - self.start[clip]

    def next(self, flat: np.ndarray) -> np.ndarray:
        """(...) the flat index of the frame after each of ``flat`` (...) in its clip; its
        last at the clip's end."""
        return np.minimum(flat + 1, self.last[np.searchsorted(self.last, flat)])

    def at_end(self, flat: np.ndarray) -> np.ndarray:
        """(...) whether each flat index is its clip's last frame."""
        return np.isin(flat, self.last)


def clip_library(clips: Sequence[ReferenceClip], *, fps: float) -> ClipLibrary:
    """The library of one humanoid's ``clips`` (non-empty) at ``fps``."""
    lengths = np.array([c.num_frames for c in clips])
    start = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    last = start + lengths - 1
    # The per-frame fields joined; the body's masses are one humanoid's, the first clip's.
    joined = {
        f.name: np.concatenate([getattr(c, f.name) for c in clips])
        for f in dataclasses.fields(ReferenceClip)
        if f.name not in ("name", "states", "body_mass", "body_com")
    }
    states = BodyState(
        *(
            np.concatenate([getattr(c.states, f.name) for c in clips])
            for f in dataclasses.fields(BodyState)
        )
    )
    clip = ReferenceClip(
        name="+".join(c.name for c in clips),
        states=states,
        body_mass=clips[0].body_mass,
        body_com=clips[0].body_com,
        **joined,
    )
    startable = np.setdiff1d(np.arange(lengths.sum()), last)
    return ClipLibrary(clip, start, last, startable, float(fps))
