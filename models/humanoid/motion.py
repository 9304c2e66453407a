"""Each fighter's lifted motion on the simulation's 30 Hz grid and its cleanup measures, as
`lift_motion` stores them, and the checks and time-series helpers the lift's steps share.

Step k of the grid lies k / 30 s into the video, whatever the video's frame rate. A fighter that
was not lifted at some steps has no rows there: `FighterMotion.step` has gaps, and
`FighterMotion.on_grid` puts NaN (False for contacts) in them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from models.humanoid.boxer import BoneLengths

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


def fighter_distance(qpos_a: np.ndarray, qpos_b: np.ndarray) -> np.ndarray:
    """Horizontal pelvis-to-pelvis distance of two fighters: (T,) metres from (T, 35) qpos each
    (the root body is the pelvis; its x, y are qpos[:, :2])."""
    return np.linalg.norm(np.asarray(qpos_a)[:, :2] - np.asarray(qpos_b)[:, :2], axis=-1)


@dataclass(frozen=True, eq=False)
class FighterSeries:
    """One fighter's cleanup measures per step; NaN at the steps where it was not lifted.

    Attributes:
        contact_slide_m_s: (S, 2) foot skating: horizontal speed of the left and right sole
            (heel-toe midpoint) from the step before, for a foot in contact at both steps;
            NaN for a foot in the air (it cannot skate) and at step 0.
        floor_penetration_m: (S,) how deep the deepest geom is below the floor, 0 if none.
    """

    contact_slide_m_s: np.ndarray
    floor_penetration_m: np.ndarray


@dataclass(frozen=True, eq=False)
class LiftSeries:
    """A lift output's cleanup measures over its S steps of the 30 Hz grid (step k at k / 30 s).

    Attributes:
        time_s: (S,) seconds into the video.
        fighters: role ("adversary", "opponent") -> its series, for the roles lifted.
        fighter_distance_m: (S,) horizontal pelvis-to-pelvis distance; NaN where either
            fighter is missing (all NaN with fewer than two fighters).
    """

    time_s: np.ndarray
    fighters: dict[str, FighterSeries]
    fighter_distance_m: np.ndarray


def grid_steps(fighters: Mapping[str, FighterMotion]) -> int:
    """How many 30 Hz steps the fighters span together: one past the last lifted step."""
    return max((int(m.step[-1]) + 1 for m in fighters.values() if len(m.step)), default=0)


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
