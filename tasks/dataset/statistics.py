"""Per-fighter statistics an analyst reads: how often and how long he punches, how he steps,
where he holds his hands, how far he stays from his opponent and which foot leads.

After the MSc thesis's analysis of its boxing data (Saarland 2021, §3.3: punch counts per
hand, punch durations, step statistics), per minute so that fighters and videos compare.

One call of `fighter_statistics` describes one contiguous clip. A fighter seen in several
clips gets one `FighterStatistics` per clip, merged by `combine`: rates and per-frame means
weighted by each clip's duration, per-punch and per-step means weighted by their counts,
distributions concatenated. Combining the statistics of the pieces of a clip gives the
statistics of the whole clip (when no punch or step is cut).

Shape letters: T frames, 33 BlazePose landmarks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from models.humanoid.kinematics import heading_yaw
from models.pose.types import BLAZEPOSE_33
from tasks.dataset.labels import HANDS, KINDS, Punch, Step

# Every scalar `fighter_statistics` can give, with its meaning.
SCALARS: dict[str, str] = {
    "minutes": "length of the footage, minutes",
    "punches_per_min": "punches per minute, both hands",
    **{f"punches_per_min_{hand}": f"{hand}-hand punches per minute" for hand in HANDS},
    **{f"punches_per_min_{kind}": f"{kind} punches per minute" for kind in KINDS},
    "punch_duration_mean_s": "mean punch duration, start to end, seconds (only with punches)",
    "distance_mean_m": "mean horizontal root-to-root distance to the opponent, metres (only "
    "with an opponent)",
    "guard_height_mean_m": "mean over frames and both hands of wrist height minus nose "
    "height, metres (negative: hands below the nose)",
    "steps_per_min": "steps per minute, both feet",
    "step_length_mean_m": "mean step length, metres (only with steps)",
    "orthodox_share": "fraction of frames with the left foot leading",
}
# Every distribution, with what one sample is.
DISTRIBUTIONS: dict[str, str] = {
    "distance_m": "per frame: horizontal root-to-root distance to the opponent, metres",
    "guard_height_m": "per frame: mean over both hands of wrist height minus nose height, m",
    "punch_duration_s": "per punch: start to end, seconds",
    "step_length_m": "per step: its length, metres",
}
# Scalars that are means over frames, and the distribution each is the mean of.
_FRAME_MEANS = {"distance_mean_m": "distance_m", "guard_height_mean_m": "guard_height_m"}
# Scalars that are means over events, and their distributions.
_EVENT_MEANS = {"punch_duration_mean_s": "punch_duration_s", "step_length_mean_m": "step_length_m"}

_INDEX = {name: i for i, name in enumerate(BLAZEPOSE_33)}


@dataclass(frozen=True, eq=False)
class FighterStatistics:
    """A fighter's statistics over some footage.

    Attributes:
        scalars: name (a key of SCALARS) -> finite value; a statistic that cannot be computed
            (no opponent, no punches, no steps) is left out.
        distributions: name (every key of DISTRIBUTIONS) -> 1-D float samples, possibly empty.
    """

    scalars: dict[str, float]
    distributions: dict[str, np.ndarray]


def _array(name: str, value: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} must be finite")
    return a


def fighter_statistics(
    *,
    punches: list[Punch],
    steps: list[Step],
    keypoints: np.ndarray,
    root_pos: np.ndarray,
    root_quat: np.ndarray,
    opponent_root: np.ndarray | None,
    rate: float,
) -> FighterStatistics:
    """Statistics of one fighter over one contiguous clip.

    Args:
        punches: the clip's punches (`label_punches`), frames in [0, T).
        steps: the clip's steps (`label_steps`), frames in [0, T].
        keypoints: (T, 33, 3) BlazePose-order 3D keypoints, world metres, z up.
        root_pos: (T, 3) the fighter's pelvis position.
        root_quat: (T, 4) the fighter's pelvis quaternion (w, x, y, z).
        opponent_root: (T, 3) the opponent's pelvis position, or None without one.
        rate: frames per second.

    Returns:
        the statistics (see SCALARS and DISTRIBUTIONS). The lead foot is the ankle further
        along the direction to the opponent, or along the fighter's facing direction without
        an opponent (or where the two roots coincide on the floor).
    """
    if not (isinstance(rate, int | float) and math.isfinite(rate) and rate > 0):
        raise ValueError(f"rate must be a finite positive frame rate, got {rate!r}")
    k = np.asarray(keypoints, dtype=np.float64)
    if k.ndim != 3 or k.shape[1:] != (len(BLAZEPOSE_33), 3) or len(k) == 0:
        raise ValueError(
            f"keypoints must have shape (T, {len(BLAZEPOSE_33)}, 3) with T >= 1, got {k.shape}"
        )
    k = _array("keypoints", k, k.shape)
    frames = len(k)
    root = _array("root_pos", root_pos, (frames, 3))
    quat = _array("root_quat", root_quat, (frames, 4))
    opponent = None if opponent_root is None else _array("opponent_root", opponent_root, root.shape)
    for p in punches:
        if p.end >= frames:
            raise ValueError(f"punch ends at frame {p.end}, outside a clip of {frames} frames")
    for s in steps:
        if not 0 < s.lift_off < s.touch_down < frames:
            raise ValueError(
                f"step from {s.lift_off} to {s.touch_down} is not inside a clip of {frames} frames"
            )

    minutes = frames / rate / 60.0
    scalars = {"minutes": minutes, "punches_per_min": len(punches) / minutes}
    for hand in HANDS:
        count = sum(p.hand == hand for p in punches)
        scalars[f"punches_per_min_{hand}"] = count / minutes
    for kind in KINDS:
        count = sum(p.kind == kind for p in punches)
        scalars[f"punches_per_min_{kind}"] = count / minutes
    scalars["steps_per_min"] = len(steps) / minutes

    nose = k[:, _INDEX["nose"], 2]
    wrists = k[:, [_INDEX[f"{hand}_wrist"] for hand in HANDS], 2]
    distributions = {
        "distance_m": np.zeros(0),
        "guard_height_m": (wrists - nose[:, None]).mean(axis=1),
        "punch_duration_s": np.array([(p.end - p.start) / rate for p in punches], dtype=float),
        "step_length_m": np.array([s.length_m for s in steps], dtype=float),
    }

    yaw = heading_yaw(quat)
    direction = np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)
    if opponent is not None:
        towards = opponent[:, :2] - root[:, :2]
        distance = np.linalg.norm(towards, axis=-1)
        distributions["distance_m"] = distance
        apart = distance > 1e-9
        direction[apart] = towards[apart] / distance[apart, None]
    ankles = k[:, _INDEX["left_ankle"], :2] - k[:, _INDEX["right_ankle"], :2]
    scalars["orthodox_share"] = float(np.mean(np.sum(ankles * direction, axis=-1) > 0))

    for scalar, name in {**_FRAME_MEANS, **_EVENT_MEANS}.items():
        if len(distributions[name]):
            scalars[scalar] = float(np.mean(distributions[name]))
    return FighterStatistics(
        scalars={n: float(v) for n, v in scalars.items()}, distributions=distributions
    )


def combine(
    stats: Sequence[FighterStatistics], durations_s: Sequence[float] | None = None
) -> FighterStatistics:
    """Merge the statistics of several clips of one fighter into the statistics of them all.

    Rates (per minute) and per-frame means (distance, guard height, orthodox share) are
    weighted by each clip's duration, among the clips that have them; per-punch and per-step
    means by their counts; distributions are concatenated in the order given.

    Args:
        stats: each clip's `fighter_statistics`.
        durations_s: each clip's duration in seconds; optional, as each statistics' "minutes"
            holds it. When given, it must agree with them.

    Returns:
        the merged statistics.
    """
    stats = list(stats)
    if not stats:
        raise ValueError("stats must hold at least one FighterStatistics")
    minutes = np.array([s.scalars.get("minutes", math.nan) for s in stats], dtype=float)
    if not (np.isfinite(minutes).all() and (minutes > 0).all()):
        raise ValueError("every statistics in stats must have a positive 'minutes' scalar")
    if durations_s is not None:
        given = np.asarray(durations_s, dtype=float) / 60.0
        if given.shape != minutes.shape or not np.allclose(given, minutes, rtol=1e-6, atol=0):
            raise ValueError(
                f"durations_s must give each clip's duration ({list(minutes * 60)} s from "
                f"the statistics), got {list(np.asarray(durations_s))}"
            )
    distributions = {
        name: np.concatenate(
            [np.asarray(s.distributions.get(name, np.zeros(0)), dtype=float) for s in stats]
        )
        for name in DISTRIBUTIONS
    }
    scalars = {"minutes": float(minutes.sum())}
    time_weighted = [
        name
        for name in SCALARS
        if name.startswith(("punches_per_min", "steps_per_min"))
        or name in _FRAME_MEANS
        or name == "orthodox_share"
    ]
    for name in time_weighted:
        have = np.array([name in s.scalars for s in stats])
        if have.any():
            values = np.array([s.scalars[name] for s in stats if name in s.scalars])
            scalars[name] = float(np.average(values, weights=minutes[have]))
    for scalar, name in _EVENT_MEANS.items():
        if len(distributions[name]):
            scalars[scalar] = float(np.mean(distributions[name]))
    return FighterStatistics(scalars=scalars, distributions=distributions)


def combine_videos(
    scalars: Sequence[tuple[str, str, str, float]],
    samples: Sequence[tuple[str, str, str, Sequence[float]]],
) -> dict[str, FighterStatistics]:
    """Role -> its statistics over every video (`combine`, in the rows' video order), from
    (video_id, role, name, value) scalar rows and (video_id, role, name, samples) distribution
    rows, as `dataset_statistics` and `dataset_distributions` hold them."""
    numbers: dict[tuple[str, str], dict[str, float]] = {}
    for video_id, role, name, value in scalars:
        numbers.setdefault((video_id, role), {})[name] = value
    distributions: dict[tuple[str, str], dict[str, np.ndarray]] = {}
    for video_id, role, name, values in samples:
        distributions.setdefault((video_id, role), {})[name] = np.asarray(values, dtype=float)
    by_role: dict[str, list[FighterStatistics]] = {}
    for (video_id, role), values in numbers.items():
        piece = FighterStatistics(values, distributions.get((video_id, role), {}))
        by_role.setdefault(role, []).append(piece)
    return {role: combine(pieces) for role, pieces in by_role.items()}
