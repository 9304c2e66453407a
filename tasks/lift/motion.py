"""Each fighter's lifted motion on the simulation's 30 Hz grid, as `lift_motion` stores it, and
the checks and time-series helpers the lift's steps share.

Step k of the grid lies k / 30 s into the video, whatever the video's frame rate. A fighter that
was not lifted at some steps has no rows there: `FighterMotion.step` has gaps, and
`FighterMotion.on_grid` puts NaN (False for contacts) in them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import mujoco
import numpy as np

from models.humanoid.boxer import BoneLengths, single_scene_mjcf
from models.humanoid.kinematics import NV

# The rate every motion is stored at, whatever the video's: the simulation's policy rate.
RATE = 30.0


@dataclass(frozen=True, eq=False)
class FighterMotion:
    """One fighter's lifted motion: N steps of the 30 Hz grid (step k at k / 30 s)."""

    step: np.ndarray  # (N,) int, increasing
    qpos: np.ndarray  # (N, 35)
    qvel: np.ndarray  # (N, 34)
    joints: np.ndarray  # (N, 33, 3) BlazePose-order keypoints, world metres
    contacts: np.ndarray  # (N, 2) bool, left and right foot
    bones: BoneLengths

    def rows(self, steps: np.ndarray) -> np.ndarray:
        """Row indices of ``steps`` (which must all be present)."""
        return np.searchsorted(self.step, steps)

    def on_grid(self, values: np.ndarray, steps: int) -> np.ndarray:
        """``values`` (N, ...), one row per lifted step, spread over steps 0..steps-1: NaN
        (False for a bool array) at the steps where the fighter was not lifted."""
        values = np.asarray(values)
        fill = False if values.dtype == bool else np.nan
        dtype = bool if values.dtype == bool else np.float64
        out = np.full((steps, *values.shape[1:]), fill, dtype=dtype)
        out[self.step] = values
        return out


def grid_steps(fighters: Mapping[str, FighterMotion]) -> int:
    """How many 30 Hz steps the fighters span together: one past the last lifted step."""
    return max((int(m.step[-1]) + 1 for m in fighters.values() if len(m.step)), default=0)


def resample(
    qpos: np.ndarray,
    joints: np.ndarray,
    contacts: np.ndarray,
    *,
    fps: float,
    rate: float,
    bones: BoneLengths,
) -> FighterMotion:
    """A motion at the video's ``fps`` (F frames, NaN rows where not lifted) on the ``rate`` grid.

    Positions, hinge angles and joints are interpolated linearly and the root quaternion by
    normalised interpolation, between the two frames around each step; steps without a lifted
    frame on both sides are left out. Contacts come from the nearer frame; qvel is recomputed
    on the grid, by central differences within each unbroken run of steps, on a humanoid of
    ``bones``.
    """
    model = mujoco.MjModel.from_xml_string(single_scene_mjcf(bones))
    frames = len(qpos)
    last = (frames - 1) / fps
    step = np.arange(int(math.floor(last * rate + 1e-9)) + 1)
    at = step / rate * fps
    lo = np.minimum(np.floor(at).astype(int), frames - 1)
    hi = np.minimum(lo + 1, frames - 1)
    w = (at - lo)[:, None]
    ok = np.isfinite(qpos[lo]).all(1) & np.isfinite(qpos[hi]).all(1)
    step, lo, hi, w = step[ok], lo[ok], hi[ok], w[ok]
    q = (1 - w) * qpos[lo] + w * qpos[hi]
    quat_lo, quat_hi = qpos[lo, 3:7], qpos[hi, 3:7]
    quat_hi = np.where((np.sum(quat_lo * quat_hi, axis=1) < 0)[:, None], -quat_hi, quat_hi)
    quat = (1 - w) * quat_lo + w * quat_hi
    q[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    j = (1 - w[:, :, None]) * joints[lo] + w[:, :, None] * joints[hi]
    c = contacts[np.where(w[:, 0] < 0.5, lo, hi)]
    v = np.zeros((len(step), NV))
    breaks = np.flatnonzero(np.diff(step) > 1) + 1
    for run in np.split(np.arange(len(step)), breaks):
        if len(run):
            v[run] = velocities(model, q[run], rate)
    return FighterMotion(step, q, v, j, c, bones)


def gaussian_smooth(values: np.ndarray, sigma: float) -> np.ndarray:
    """Zero-phase Gaussian filter along axis 0, with odd reflection at the ends.

    Odd reflection (2 x_0 - x_k) keeps a linear trend through the ends, so a moving root
    is not pulled back at the start and end of a clip.

    Args:
        values: (T, ...) samples.
        sigma: standard deviation in samples; 0 returns a copy.

    Returns:
        (T, ...) filtered copy.
    """
    x = np.asarray(values, dtype=np.float64)
    if sigma <= 0 or len(x) < 2:
        return x.copy()
    half = min(int(math.ceil(3 * sigma)), len(x) - 1)
    kernel = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma) ** 2)
    kernel /= kernel.sum()
    head = 2 * x[:1] - x[1 : half + 1][::-1]
    tail = 2 * x[-1:] - x[-half - 1 : -1][::-1]
    padded = np.concatenate([head, x, tail])
    out = np.zeros_like(x)
    for k, w in enumerate(kernel):
        out += w * padded[k : k + len(x)]
    return out


def velocities(model: mujoco.MjModel, qpos: np.ndarray, fps: float) -> np.ndarray:
    """qvel (T, nv) by central differences of qpos with `mj_differentiatePos` (one-sided at
    the ends; zeros for a single frame)."""
    frames = len(qpos)
    qvel = np.zeros((frames, model.nv))
    if frames < 2:
        return qvel
    dt = 1.0 / fps
    for frame in range(frames):
        a, b = max(frame - 1, 0), min(frame + 1, frames - 1)
        mujoco.mj_differentiatePos(model, qvel[frame], (b - a) * dt, qpos[a], qpos[b])
    return qvel


def check_array(name: str, value: np.ndarray, shape: tuple[int | None, ...]) -> np.ndarray:
    """`value` as float64, or ValueError naming `name` unless its shape matches (None: any)."""
    array = np.asarray(value, dtype=np.float64)
    if array.ndim != len(shape) or any(
        want is not None and got != want for got, want in zip(array.shape, shape, strict=True)
    ):
        letters = "(" + ", ".join("T" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name} must have shape {letters}, got {array.shape}")
    return array


def check_fps(fps: float) -> float:
    if (
        isinstance(fps, bool)
        or not isinstance(fps, int | float)
        or not (math.isfinite(fps) and fps > 0)
    ):
        raise ValueError(f"fps must be a positive frame rate, got {fps!r}")
    return float(fps)


def clean_runs(mask: np.ndarray, min_frames: int) -> np.ndarray:
    """A boolean sequence with short gaps filled, then short runs dropped, per column.

    Args:
        mask: (T, ...) bool.
        min_frames: gaps (False runs between two True runs) and True runs shorter than this
            are flipped; 0 or 1 leaves `mask` as it is.

    Returns:
        (T, ...) bool, a new array.
    """
    m = np.array(mask, dtype=bool, copy=True)
    if min_frames <= 1 or m.size == 0:
        return m
    flat = m.reshape(len(m), -1)
    for column in flat.T:
        for value, fill in ((False, True), (True, False)):
            for start, stop in runs(column == value):
                inner = value or (start > 0 and stop < len(column))  # gaps: between runs only
                if inner and stop - start < min_frames:
                    column[start:stop] = fill
    return flat.reshape(m.shape)


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True in a 1-D bool array."""
    padded = np.concatenate([[False], mask, [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True))


def horizontal_speed(positions: np.ndarray, fps: float, *, half: int = 2) -> np.ndarray:
    """Speed (m/s) from the displacement over 2 `half` frames centred on each frame
    (|x[t + half] - x[t - half]| / (2 half / fps), the window shrunk at the clip's ends),
    which averages out frame-to-frame noise that a one-frame difference would count.

    Args:
        positions: (T, ..., 2) or (T, ..., 3) positions; only the first two coordinates count.
        fps: frames per second.

    Returns:
        (T, ...) speeds; zeros for a single frame.
    """
    p = np.asarray(positions, dtype=np.float64)[..., :2]
    frames = len(p)
    if frames < 2:
        return np.zeros(p.shape[:-1])
    index = np.arange(frames)
    ahead = np.minimum(index + half, frames - 1)
    behind = np.maximum(index - half, 0)
    span = (ahead - behind).reshape(-1, *([1] * (p.ndim - 2)))
    return np.linalg.norm(p[ahead] - p[behind], axis=-1) / span * fps
