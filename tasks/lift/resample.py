"""A lifted motion at the video's frame rate put on the simulation's 30 Hz grid
(`models.humanoid.motion.FighterMotion`)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import mujoco
import numpy as np

from models.humanoid.boxer import BoneLengths, single_scene_mjcf
from models.humanoid.compiled import velocities
from models.humanoid.kinematics import NV
from models.humanoid.motion import FighterMotion


def resample(
    qpos: np.ndarray,
    joints: np.ndarray,
    contacts: np.ndarray,
    *,
    fps: float,
    rate: float,
    bones: BoneLengths,
    cuts: Sequence[int] = (),
) -> FighterMotion:
    """A motion at the video's ``fps`` (F frames, NaN rows where not lifted) on the ``rate`` grid.

    Positions, hinge angles and joints are interpolated linearly and the root quaternion by
    normalised interpolation, between the two frames around each step; steps without a lifted
    frame on both sides, or with a cut between them (``cuts``: the frames where a shot starts),
    are left out. Contacts come from the nearer frame; qvel is recomputed on the grid, by
    central differences within each unbroken run of steps of one shot, on a humanoid of
    ``bones``: each shot has its own camera and world, so no velocity is taken across a cut.
    """
    model = mujoco.MjModel.from_xml_string(single_scene_mjcf(bones))
    frames = len(qpos)
    last = (frames - 1) / fps
    step = np.arange(int(math.floor(last * rate + 1e-9)) + 1)
    at = step / rate * fps
    lo = np.minimum(np.floor(at + 1e-9).astype(int), frames - 1)
    w = np.clip(at - lo, 0.0, 1.0)[:, None]
    # A step on a frame needs no second frame (the last frame of a shot has none in its shot).
    hi = np.where(w[:, 0] > 1e-9, np.minimum(lo + 1, frames - 1), lo)
    shot = np.searchsorted(np.sort(np.asarray(cuts, dtype=int)), np.arange(frames), side="right")
    ok = np.isfinite(qpos[lo]).all(1) & np.isfinite(qpos[hi]).all(1) & (shot[lo] == shot[hi])
    step, lo, hi, w = step[ok], lo[ok], hi[ok], w[ok]
    q = (1 - w) * qpos[lo] + w * qpos[hi]
    quat_lo, quat_hi = qpos[lo, 3:7], qpos[hi, 3:7]
    quat_hi = np.where((np.sum(quat_lo * quat_hi, axis=1) < 0)[:, None], -quat_hi, quat_hi)
    quat = (1 - w) * quat_lo + w * quat_hi
    q[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    j = (1 - w[:, :, None]) * joints[lo] + w[:, :, None] * joints[hi]
    c = contacts[np.where(w[:, 0] < 0.5, lo, hi)]
    v = np.zeros((len(step), NV))
    breaks = np.flatnonzero((np.diff(step) > 1) | (np.diff(shot[lo]) != 0)) + 1
    for run in np.split(np.arange(len(step)), breaks):
        if len(run):
            v[run] = velocities(model, q[run], rate)
    return FighterMotion(step, q, v, j, c, bones)
