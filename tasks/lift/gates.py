"""Plausibility gates: what no boxer can do is refused before it reaches the dataset.

A monocular lift can go badly wrong where its input is thin: at the ends of tracks (a person
half hidden by an occluder placed hundreds of metres away), for small people far off, or when
the floor is found under the wrong feet. The lift stage judges each fighter's frames and each
shot with the bounds of `GateConfig` and drops what fails (the dataset stage cuts its clips at
the gaps), counting it per reason as `frames_rejected_<reason>` metrics:

- ``one_person``: both roles on one person (the tracker followed one body twice): their 2D
  keypoints closer, at the median over the joints, than `one_person_share` of the body's
  height in the image; both fighters' frames are dropped, as either may be the wrong one;
- ``depth``: the pelvis further from the camera than `max_depth_m`;
- ``speed``: where a skeleton is first placed, its distance from the camera changing by more
  than a factor `max_depth_ratio` from one frame to the next; once lifted, the pelvis moving
  faster than `max_root_speed_m_s` (both frames of such a step are dropped: either may be
  the wrong one);
- ``floating``: the cleanup had to lower the fighter by more than `max_floor_settle_m` to put
  him on the floor (`tasks.lift.cleanup.settle_on_floor`): the floor under him is wrong;
- ``shot``: the whole shot, when the camera found for it is higher than
  `max_camera_height_m` or the two fighters are further apart than `max_fighter_distance_m`
  (the floor or the scale is wrong for everyone in it);
- ``short``: believed frames of a fighter in a shot too few (under `lift.min_frames`) to lift
  once the others are dropped.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from models.settings import setting

REASONS = ("one_person", "depth", "speed", "floating", "shot", "short")


@dataclass(frozen=True)
class GateConfig:
    """Bounds on what a lifted boxer can be: frames and shots outside them are dropped."""

    one_person_share: float = setting(
        0.1,
        "Two fighters whose 2D keypoints lie closer than this share of the body's height in the "
        "image (median over the joints) are one person tracked twice (the sample's two walkers "
        "never come closer than 0.41).",
    )
    max_depth_m: float = setting(
        40.0,
        "A fighter's pelvis further than this from the camera (m) is not believed (a ringside "
        "camera films a ring of 5-7 m from a few metres to about 30 m away).",
    )
    max_root_speed_m_s: float = setting(
        8.0,
        "Fastest pelvis speed believed from one frame to the next (m/s; boxers' steps and "
        "lunges stay under about 5 m/s, DeepMimic's run reaches 4.4 and the sample's walkers "
        "1.4 (benchmarks/gate_margins.py), sprinters 10-12).",
    )
    max_depth_ratio: float = setting(
        1.5,
        "Largest factor by which a fighter's distance from the camera may change from one frame "
        "to the next where the skeleton is first placed, before the lift smooths it (that "
        "placement is noisy: on the sample it changes by up to 1.11 per frame, "
        "benchmarks/gate_margins.py).",
    )
    max_floor_settle_m: float = setting(
        1.0,
        "A fighter the cleanup has to lower by more than this (m) to stand on the floor is on "
        "a floor found wrongly, and those frames are dropped (a person on a rooftop was lifted "
        "1.9 m over the floor; the monocular lift places the sample's walkers up to 0.35 m "
        "high: benchmarks/gate_margins.py).",
    )
    max_camera_height_m: float = setting(
        12.0, "A shot whose camera is found higher than this above the floor (m) is left out."
    )
    max_fighter_distance_m: float = setting(
        10.0,
        "A shot whose two fighters are placed further apart than this (m, median over the "
        "frames both are seen) is left out: no ring is that large.",
    )
    note_share: float = setting(
        0.05, "A note names every reason that dropped at least this share (0-1) of the frames."
    )

    def __post_init__(self) -> None:
        if not self.max_depth_ratio > 1:
            raise ValueError(
                f"lift.gates.max_depth_ratio must be > 1, got {self.max_depth_ratio!r}"
            )
        for name in ("one_person_share", "max_depth_m", "max_root_speed_m_s", "max_floor_settle_m",
                     "max_camera_height_m", "max_fighter_distance_m"):  # fmt: skip
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
                raise ValueError(f"lift.gates.{name} must be a positive number, got {value!r}")
        if not 0.0 <= self.note_share <= 1.0:
            raise ValueError(f"lift.gates.note_share must be in [0, 1], got {self.note_share!r}")


def one_person(first: np.ndarray, second: np.ndarray, config: GateConfig) -> np.ndarray:
    """(F,) bool: frames in which two fighters' 2D keypoints (F, J, 2 pixels, NaN where unseen)
    lie on one body: median joint distance under `one_person_share` of the first's height in
    the image. Frames where either is unseen are not flagged."""
    a, b = np.asarray(first, dtype=np.float64), np.asarray(second, dtype=np.float64)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN frames: unseen, not flagged
        apart = np.nanmedian(np.linalg.norm(a - b, axis=-1), axis=1)
        height = np.nanmax(a[..., 1], axis=1) - np.nanmin(a[..., 1], axis=1)
    return np.nan_to_num(apart / height, nan=np.inf) < config.one_person_share


def too_far(roots: np.ndarray, camera_centre: np.ndarray, config: GateConfig) -> np.ndarray:
    """(T,) bool: pelvis positions (T, 3) further than `max_depth_m` from the camera centre
    (3,); NaN rows are not flagged (they are gaps already)."""
    distance = np.linalg.norm(np.asarray(roots) - np.asarray(camera_centre), axis=-1)
    return np.nan_to_num(distance, nan=0.0) > config.max_depth_m


def too_fast(roots: np.ndarray, fps: float, config: GateConfig) -> np.ndarray:
    """(T,) bool: both frames of every step between consecutive frames in which the pelvis
    (T, 3) moves faster than `max_root_speed_m_s`."""
    roots = np.asarray(roots, dtype=np.float64)
    flagged = np.zeros(len(roots), bool)
    if len(roots) < 2:
        return flagged
    step = np.linalg.norm(np.diff(roots, axis=0), axis=-1) * fps
    fast = np.nan_to_num(step, nan=0.0) > config.max_root_speed_m_s
    flagged[:-1] |= fast
    flagged[1:] |= fast
    return flagged


def depth_jumps(roots_camera: np.ndarray, config: GateConfig) -> np.ndarray:
    """(T,) bool: both frames of every step between consecutive frames in which the distance
    of the pelvis (T, 3, camera coordinates) from the camera changes by more than a factor
    `max_depth_ratio`: a placement blown up, not a body moving."""
    depth = np.linalg.norm(np.asarray(roots_camera, dtype=np.float64), axis=-1)
    flagged = np.zeros(len(depth), bool)
    if len(depth) < 2:
        return flagged
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.maximum(depth[1:], depth[:-1]) / np.minimum(depth[1:], depth[:-1])
    jump = np.nan_to_num(ratio, nan=1.0) > config.max_depth_ratio
    flagged[:-1] |= jump
    flagged[1:] |= jump
    return flagged


def floating(settle_m: np.ndarray, config: GateConfig) -> np.ndarray:
    """(T,) bool: frames the cleanup lowered (per-frame drop in metres) by more than
    `max_floor_settle_m`."""
    return np.asarray(settle_m) > config.max_floor_settle_m


def shot_problem(
    camera_height_m: float, fighter_distance_m: float | None, config: GateConfig
) -> str | None:
    """Why a shot cannot be used, in words, or None when its camera and scale are believable.

    ``fighter_distance_m`` is the median distance between the two fighters' pelvises over
    the frames both are seen (None with one fighter)."""
    if (
        not math.isfinite(camera_height_m)
        or not 0.0 < camera_height_m <= config.max_camera_height_m
    ):
        return (
            f"its camera was found {camera_height_m:.1f} m above the floor "
            f"(lift.gates.max_camera_height_m is {config.max_camera_height_m:g})"
        )
    if fighter_distance_m is not None and not fighter_distance_m <= config.max_fighter_distance_m:
        return (
            f"its fighters were placed {fighter_distance_m:.1f} m apart "
            f"(lift.gates.max_fighter_distance_m is {config.max_fighter_distance_m:g})"
        )
    return None


def notes(rejected: dict[str, int], frames: int, config: GateConfig) -> list[str]:
    """One line per reason that dropped at least `note_share` of ``frames`` fighter-frames."""
    if frames <= 0:
        return []
    return [
        f"{count} of {frames} fighter-frames ({count / frames:.0%}) dropped as implausible: "
        f"{reason} (see lift.gates)"
        for reason, count in rejected.items()
        if count and count / frames >= config.note_share
    ]
