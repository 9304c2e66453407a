"""The cleanup's measures step by step: what the dashboard plots over a lifted video. The lift
stage measures them on its output and stores them with it (`lift_motion`); the dashboard reads
them back (`tasks.lift.store.lift_series`).

`cleanup_series` measures a lift output's stored motion (`lift_motion`, the 30 Hz grid) with the
functions the cleanup's own summary metrics use (`tasks.lift.cleanup.floor_depth`,
`tasks.lift.cleanup.contact_slide`, `fighter_distance`), so each summary metric is an aggregate of
a series: ``floor_penetration_max_mm`` its maximum, ``floor_penetration_mean_mm`` its mean,
``contact_slide_cm_per_frame`` the mean slide per frame of the feet in contact,
``fighter_distance_mean_m`` the mean distance. The summaries are taken at the video's frame
rate before resampling, so on a real video they agree with the series to within what the
resampling changes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import mujoco
import numpy as np

from models.humanoid.boxer import single_scene_mjcf
from models.humanoid.fitting import Skeleton
from models.humanoid.motion import (
    RATE,
    FighterMotion,
    FighterSeries,
    LiftSeries,
    fighter_distance,
    grid_steps,
)
from tasks.lift.cleanup import contact_slide, floor_depth, sole_positions


def _fighter_series(
    motion: FighterMotion, steps: int, rate: float, cuts: Sequence[int]
) -> FighterSeries:
    model = mujoco.MjModel.from_xml_string(single_scene_mjcf(motion.bones))
    soles = motion.on_grid(sole_positions(Skeleton.from_model(model), motion.qpos), steps)
    contacts = motion.on_grid(motion.contacts, steps)
    speed = np.full((steps, 2), np.nan)
    # A step the fighter is missing at has no contacts, so no slide is measured across it.
    speed[1:] = contact_slide(soles, contacts) * rate
    # A foot "moves" between two shots' worlds at a cut: no slide is measured across one.
    speed[[c for c in cuts if 0 < c < steps]] = np.nan
    return FighterSeries(
        contact_slide_m_s=speed,
        floor_penetration_m=motion.on_grid(floor_depth(model, motion.qpos), steps),
    )


def cleanup_series(
    fighters: Mapping[str, FighterMotion], *, rate: float = RATE, cuts: Sequence[int] = ()
) -> LiftSeries:
    """Per-step foot skating, floor penetration and distance between the fighters.

    Args:
        fighters: role -> its motion on the ``rate`` grid (`tasks.lift.store.load_motion`).
        rate: steps per second of the grid.
        cuts: the first step of each shot after the first (no slide is taken across a cut).

    Returns:
        The series over steps 0 .. (last step of either fighter); see `LiftSeries`.
    """
    steps = grid_steps(fighters)
    series = {role: _fighter_series(m, steps, rate, cuts) for role, m in fighters.items()}
    distance = np.full(steps, np.nan)
    if len(fighters) == 2:
        a, b = (m.on_grid(m.qpos, steps) for m in fighters.values())
        distance = fighter_distance(a, b)  # NaN where either is missing
    return LiftSeries(time_s=np.arange(steps) / rate, fighters=series, fighter_distance_m=distance)


def motion_columns(
    fighters: Mapping[str, FighterMotion], series: LiftSeries
) -> dict[str, np.ndarray]:
    """The ``lift_motion`` columns of each fighter's motion, with its per-step floor
    penetration and contact slide from ``series`` (`cleanup_series` of the same motion)."""
    parts: dict[str, list[np.ndarray]] = {}
    for role, m in fighters.items():
        measured = series.fighters[role]
        values = {
            "role": np.array([role] * len(m.step)),
            "step": m.step.astype(np.int64),
            "time_s": m.step / RATE,
            "qpos": m.qpos.astype(np.float32),
            "qvel": m.qvel.astype(np.float32),
            # Not reshape(T, -1): a fighter with no believed frame has T = 0.
            "joints": m.joints.reshape(len(m.step), math.prod(m.joints.shape[1:])).astype(
                np.float32
            ),
            "contact_left": m.contacts[:, 0],
            "contact_right": m.contacts[:, 1],
            "floor_penetration_m": measured.floor_penetration_m[m.step],
            "slide_left_m_s": measured.contact_slide_m_s[m.step, 0],
            "slide_right_m_s": measured.contact_slide_m_s[m.step, 1],
        }
        for name, value in values.items():
            parts.setdefault(name, []).append(value)
    return {name: np.concatenate(values) for name, values in parts.items()}
