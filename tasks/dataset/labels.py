"""Automatic punch labels and steps from a fighter's 3D keypoints and foot contacts.

Punches follow the MSc thesis's automatic labelling (Saarland 2021, §3.2, Algorithms 1 and
2), read robustly for video-derived 3D, which wiggles by millimetres to centimetres. Two
signals per hand: the shoulder-wrist distance d (every punch reaches out) and the wrist's
height above the same shoulder h (uppercuts rise; the thesis uses the neck's height, for
which BlazePose has no landmark). Each signal goes through the same steps (`_strokes`):

1. Turns (Algorithm 1's Search_Threshold S). As printed, ``Hand_Distance > Search_Threshold``
   holds for any arm, and the first frame where d shrinks at all, a wiggle included, ends
   the search. We read S as a hysteresis: a top counts only once the signal has risen at
   least S from the last low and then fallen at least S from the top (a zig-zag, `_turns`).
   On noisy keypoints S is raised to `NOISE_TURNS` times the signal's own noise (`_noise`).
2. Full extension (Algorithm 1's frame): the first frame within S of the top where the
   signal stops growing (grows by less than `GROW_FRACTION` of S in a frame). A held
   extension (DeepMimic's punch holds 0.7 s) lasts to the last frame within S of the top
   before the next low, and is followed to its retraction for at most `HOLD_WINDOWS` windows.
3. Start and end (Algorithm 2's Punch_Threshold P and its 25-frame search, the window W):
   the signal must come P below the top within W before the full extension, or within W
   after the hold. The thesis's uppercut rule, "wrist below the shoulder", is replaced by the
   same P rule on h, because a high guard holds the wrists above the shoulders. The start and
   end are then put where the motion begins and ends rather than at the crossing: the start
   is the last frame, and the end the first, within `ONSET_FRACTION` of S of the lowest
   signal in its window. A punch thus runs from the onset of the reach (or rise) to the end
   of the retraction.
4. Which tops are punches. On d, P must be found on at least one side: the first jab of a
   double jab is not retracted far, the second does not start from the guard. A top with
   neither (the thesis's fallback of 25 frames on both sides) is no punch. On h, P must be
   found on both sides and the top be above the shoulder, so that raising the guard is no
   uppercut; a rise overlapping a reach of the same hand is the same punch. Either way, at
   full extension and at the top the wrist must be at least `FORWARD_MIN` arms in front of
   its shoulder along the start frame's facing direction and the arm at most
   `LOWEST_REACH_DEG` below the horizontal: an arm swung back (running) or hanging down
   (dropping the guard lengthens d by more than P) is neither.

S and P are the thesis's values for its actor's arm, scaled by the fighter's arm over
`THESIS_ARM_M`; W is `PunchConfig.window_s` at the clip's rate, rounded.

The kind comes from the wrist's path from start to full extension, in the heading frame of
the start frame (x the pelvis's facing direction on the floor, y left, z up; the start's,
because the hips turn during a punch): an uppercut when the wrist rises more than it travels
horizontally (steeper than 45 degrees), a hook when it travels more sideways than forward or
its horizontal path bows out from its chord by at least `HOOK_BULGE` of the chord's length,
a straight otherwise.

Steps: a foot's step runs from the frame its floor contact ends to the frame contact
resumes; its length is the horizontal distance between the foot's positions at the last
contact frame before lift-off and at touch-down.

Shape letters: T frames, 33 BlazePose landmarks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.humanoid.kinematics import heading_frame
from models.humanoid.motion import runs
from models.pose.types import BLAZEPOSE_33
from tasks.dataset.config import THESIS_ARM_M, PunchConfig

HANDS: tuple[str, ...] = ("left", "right")
FEET: tuple[str, ...] = ("left", "right")
KINDS: tuple[str, ...] = ("straight", "hook", "uppercut")

# Longest hold at full extension followed to its retraction, in windows (0.83 s at the
# thesis's window; the thesis's longest punch is 50 frames at 60 Hz, 0.83 s). A longer hold
# ends the punch one window after the full extension, the thesis's fallback.
HOLD_WINDOWS = 2.0
# How far in front of its shoulder, along the start frame's facing direction, the wrist must
# be at full extension, as a fraction of the arm. A hanging arm is at about 0, an arm swung
# back below 0, a guard at 0.3-0.4, a jab from a bladed stance at 0.6 or more.
FORWARD_MIN = 0.15
# Nor may the arm point more than this far below the horizontal at full extension: an arm
# hanging down (dropping the guard lengthens it by more than P) is at 70-90 degrees, a body
# shot at 20-40.
LOWEST_REACH_DEG = 45.0
# A horizontal path that bows out from its chord by this fraction of the chord is a hook's arc
# (a quarter circle bows out by 0.21, DeepMimic's straight right with its hip turn by 0.13).
HOOK_BULGE = 0.18
# A punch's start and end are within this fraction of S of the lowest signal near them.
ONSET_FRACTION = 0.25
# On noisy keypoints a turn must also be this many times the signal's noise (`_noise`), so
# that noise on a held arm does not make turns; 6 standard deviations are rarely spanned by
# the noise of a few seconds.
NOISE_TURNS = 6.0
# The signal "stops growing" when it grows by less than this fraction of S in one frame.
GROW_FRACTION = 0.25

_INDEX = {name: i for i, name in enumerate(BLAZEPOSE_33)}


@dataclass(frozen=True, eq=False)
class Punch:
    """One labelled punch (frame indices into the arrays given to `label_punches`).

    Attributes:
        hand: "left" or "right".
        kind: "straight", "hook" or "uppercut".
        start: first frame of the reach (or rise, for uppercuts).
        peak: the full extension (Algorithm 1's frame); start <= peak.
        end: last frame of the retraction; peak <= end.
        extension_m: shoulder-wrist distance at the peak, metres.
        target: (3,) wrist world position at the peak, metres.
    """

    hand: str
    kind: str
    start: int
    peak: int
    end: int
    extension_m: float
    target: np.ndarray

    def __post_init__(self) -> None:
        if self.hand not in HANDS:
            raise ValueError(f"Punch.hand must be one of {HANDS}, got {self.hand!r}")
        if self.kind not in KINDS:
            raise ValueError(f"Punch.kind must be one of {KINDS}, got {self.kind!r}")
        if not 0 <= self.start <= self.peak <= self.end:
            raise ValueError(
                f"Punch frames must satisfy 0 <= start <= peak <= end, got "
                f"{self.start}, {self.peak}, {self.end}"
            )
        target = np.array(self.target, dtype=np.float64)
        if target.shape != (3,):
            raise ValueError(f"Punch.target must have shape (3,), got {target.shape}")
        target.setflags(write=False)
        object.__setattr__(self, "target", target)


@dataclass(frozen=True)
class Step:
    """One step of one foot.

    Attributes:
        foot: "left" or "right".
        lift_off: first frame the foot is off the floor.
        touch_down: first frame it is on the floor again.
        length_m: horizontal distance between the foot's positions at the last contact frame
            before lift-off and at touch-down, metres.
    """

    foot: str
    lift_off: int
    touch_down: int
    length_m: float


# --------------------------------------------------------------------------
# Checks
# --------------------------------------------------------------------------


def _keypoints(keypoints: np.ndarray) -> np.ndarray:
    k = np.asarray(keypoints, dtype=np.float64)
    if k.ndim != 3 or k.shape[1:] != (len(BLAZEPOSE_33), 3):
        raise ValueError(
            f"keypoints must have shape (T, {len(BLAZEPOSE_33)}, 3) (BlazePose order, world "
            f"metres), got {k.shape}"
        )
    if not np.isfinite(k).all():
        raise ValueError("keypoints must be finite (one contiguous clip, no missing frames)")
    return k


def _positive(name: str, value: float) -> float:
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite positive number, got {value!r}")
    return float(value)


def _at(keypoints: np.ndarray, name: str) -> np.ndarray:
    return keypoints[:, _INDEX[name]]


# --------------------------------------------------------------------------
# Arm length
# --------------------------------------------------------------------------


def arm_length(keypoints: np.ndarray) -> float:
    """A fighter's arm: median upper arm plus median forearm, over frames and both arms.

    Args:
        keypoints: (T, 33, 3) BlazePose-order 3D keypoints, metres.

    Returns:
        shoulder-elbow plus elbow-wrist length in metres.
    """
    k = _keypoints(keypoints)
    if len(k) == 0:
        raise ValueError("keypoints must hold at least one frame")
    upper = [_at(k, f"{s}_elbow") - _at(k, f"{s}_shoulder") for s in HANDS]
    fore = [_at(k, f"{s}_wrist") - _at(k, f"{s}_elbow") for s in HANDS]
    return float(
        np.median(np.linalg.norm(np.concatenate(upper), axis=-1))
        + np.median(np.linalg.norm(np.concatenate(fore), axis=-1))
    )


# --------------------------------------------------------------------------
# Punches
# --------------------------------------------------------------------------


def _turns(signal: np.ndarray, threshold: float) -> list[tuple[int, int]]:
    """The zig-zag of `signal`: alternating highs (+1) and lows (-1), each confirmed only
    once the signal has moved `threshold` away from it.

    The last entry may be unconfirmed: the most extreme frame since the previous turn, in
    the direction the signal was last heading.

    Returns:
        [(frame, +1 for a high or -1 for a low), ...] in time order.
    """
    turns: list[tuple[int, int]] = []
    hi = lo = 0
    trend = 0
    for t in range(1, len(signal)):
        x = signal[t]
        if trend == 0:
            hi = t if x > signal[hi] else hi
            lo = t if x < signal[lo] else lo
            if signal[hi] - x >= threshold:
                turns.append((hi, 1))
                trend, lo = -1, t
            elif x - signal[lo] >= threshold:
                turns.append((lo, -1))
                trend, hi = 1, t
        elif trend == 1:
            if x > signal[hi]:
                hi = t
            elif signal[hi] - x >= threshold:
                turns.append((hi, 1))
                trend, lo = -1, t
        else:
            if x < signal[lo]:
                lo = t
            elif x - signal[lo] >= threshold:
                turns.append((lo, -1))
                trend, hi = 1, t
    if trend == 1:
        turns.append((hi, 1))
    elif trend == -1:
        turns.append((lo, -1))
    return turns


def _noise(signal: np.ndarray) -> float:
    """The standard deviation of white noise on `signal`, from its third differences.

    A third difference of white noise has 20 times its variance, while smooth motion (an arm
    swinging once in 20 frames) shrinks to a thirtieth; the median absolute value (over
    0.6745 for a normal) ignores the few frames of fast motion.
    """
    if len(signal) < 4:
        return 0.0
    third = np.diff(signal, n=3)
    return float(np.median(np.abs(third)) / 0.6745 / math.sqrt(20.0))


@dataclass(frozen=True)
class _Stroke:
    """A punch found on one signal, before its kind is known: its frames, and `top`, the
    frame where the signal is highest."""

    start: int
    peak: int
    end: int
    top: int


def _strokes(
    signal: np.ndarray, *, search: float, punch: float, window: int, both_sides: bool
) -> list[_Stroke]:
    """Algorithms 1 and 2 on one signal (d or h): see the module docstring.

    Args:
        signal: (T,) the shoulder-wrist distance or the wrist's height above the shoulder.
        search: S, metres. punch: P, metres. window: W, frames.
        both_sides: whether the signal must come P below the top both before and after it
            (else on at least one side).
    """
    n = len(signal)
    search = max(search, NOISE_TURNS * _noise(signal))
    turns = _turns(signal, search)
    tolerance = ONSET_FRACTION * search
    grow = GROW_FRACTION * search
    strokes = []
    for i, (top_frame, kind) in enumerate(turns):
        if kind != 1 or i == 0 or top_frame == n - 1:
            continue  # a low, or a top whose rise (or whose stop) the clip does not show
        low_before = turns[i - 1][0]
        low_after = turns[i + 1][0] if i + 1 < len(turns) else n - 1
        top = signal[top_frame]
        # Algorithm 1: the first frame within S of the top where the signal stops growing.
        frames = np.arange(low_before, top_frame + 1)
        near = (signal[frames] >= top - search) & (signal[frames + 1] < signal[frames] + grow)
        peak = int(frames[np.argmax(near)])
        # The hold: up to the last frame within S of the top before the next low.
        held = np.flatnonzero(signal[top_frame : low_after + 1] >= top - search)
        hold_end = top_frame + int(held[-1])
        followed = hold_end - peak <= HOLD_WINDOWS * window
        # Algorithm 2: P below the top within W before the peak / after the hold.
        first = max(low_before, peak - window)
        rose = bool(np.any(signal[first : peak + 1] <= top - punch))
        last = min(low_after, hold_end + window)
        fell = followed and bool(np.any(signal[hold_end : last + 1] <= top - punch))
        if not ((rose and fell) if both_sides else (rose or fell)):
            continue
        # The motion's onset and the retraction's end, near the lowest signal in each window.
        before = signal[first : peak + 1]
        start = first + int(np.flatnonzero(before <= before.min() + tolerance)[-1])
        if followed:
            after = signal[hold_end : last + 1]
            end = hold_end + int(np.flatnonzero(after <= after.min() + tolerance)[0])
        else:
            end = min(peak + window, n - 1)
        strokes.append(_Stroke(start, peak, end, top_frame))
    return strokes


def _aims(stroke: _Stroke, arm_vectors: np.ndarray, heading: np.ndarray, arm: float) -> bool:
    """Whether the arm at full extension points forward and not down.

    Args:
        stroke: the candidate.
        arm_vectors: (T, 3) shoulder-to-wrist vectors, world frame.
        heading: (T, 3, 3) heading frames (`heading_frame`); column 0 is the facing direction.
        arm: the fighter's arm, metres.

    Returns:
        True when, both at the full extension and where the signal is highest, the wrist is
        at least FORWARD_MIN arms in front of its shoulder along the start frame's facing
        direction and the arm at most LOWEST_REACH_DEG below the horizontal.
    """
    v = arm_vectors[[stroke.peak, stroke.top]]
    forward = v @ heading[stroke.start, :, 0]
    lowest = math.sin(math.radians(LOWEST_REACH_DEG)) * np.linalg.norm(v, axis=-1)
    return bool(np.all(forward >= FORWARD_MIN * arm) and np.all(v[:, 2] >= -lowest))


def _kind(path: np.ndarray) -> str:
    """The punch kind from the wrist's path, start to peak, in the start's heading frame.

    Args:
        path: (N, 3) wrist positions relative to the start, x forward, y left, z up.
    """
    chord = path[-1]
    horizontal = float(np.hypot(chord[0], chord[1]))
    if chord[2] > horizontal:
        return "uppercut"
    if abs(chord[1]) > chord[0]:
        return "hook"
    if horizontal > 0:
        # Largest horizontal distance of the path from its chord (2D cross product).
        bulge = np.abs(path[:, 0] * chord[1] - path[:, 1] * chord[0]).max() / horizontal
        if bulge >= HOOK_BULGE * horizontal:
            return "hook"
    return "straight"


def label_punches(
    keypoints: np.ndarray,
    root_quat: np.ndarray,
    rate: float,
    config: PunchConfig,
    arm_m: float | None = None,
) -> list[Punch]:
    """Find and classify a fighter's punches in one contiguous clip (see the module docstring).

    Args:
        keypoints: (T, 33, 3) BlazePose-order 3D keypoints, world metres, z up.
        root_quat: (T, 4) the fighter's pelvis quaternions (w, x, y, z), for the heading frame.
        rate: frames per second.
        config: the thesis's thresholds (for its 0.63 m arm) and search window.
        arm_m: the fighter's arm (shoulder to wrist) in metres; `arm_length(keypoints)` if None.

    Returns:
        the punches of both hands, sorted by peak (then hand).
    """
    k = _keypoints(keypoints)
    q = np.asarray(root_quat, dtype=np.float64)
    if q.shape != (len(k), 4) or not np.isfinite(q).all():
        raise ValueError(
            f"root_quat must be finite with shape (T, 4) = ({len(k)}, 4) to match "
            f"keypoints, got {q.shape}"
        )
    rate = _positive("rate", rate)
    for name in ("search_threshold_m", "punch_threshold_m", "window_s"):
        _positive(f"config.{name}", getattr(config, name))
    if len(k) < 3:
        return []
    arm = arm_length(k) if arm_m is None else _positive("arm_m", arm_m)
    scale = arm / THESIS_ARM_M
    search = config.search_threshold_m * scale
    punch = config.punch_threshold_m * scale
    window = max(1, math.floor(config.window_s * rate + 0.5))
    heading = heading_frame(q)  # (T, 3, 3); world v is heading.T @ v in the heading frame

    punches = []
    for hand in HANDS:
        wrist = _at(k, f"{hand}_wrist")
        arm_vectors = wrist - _at(k, f"{hand}_shoulder")
        reach = np.linalg.norm(arm_vectors, axis=-1)
        rise = arm_vectors[:, 2]
        windows = {"search": search, "punch": punch, "window": window}
        strokes = [
            s
            for s in _strokes(reach, both_sides=False, **windows)
            if _aims(s, arm_vectors, heading, arm)
        ]
        for stroke in _strokes(rise, both_sides=True, **windows):
            if (
                rise[stroke.peak] > 0
                and _aims(stroke, arm_vectors, heading, arm)
                and not any(stroke.start <= s.end and s.start <= stroke.end for s in strokes)
            ):
                strokes.append(stroke)
        for s in strokes:
            path = (wrist[s.start : s.peak + 1] - wrist[s.start]) @ heading[s.start]
            punches.append(
                Punch(
                    hand=hand,
                    kind=_kind(path),
                    start=s.start,
                    peak=s.peak,
                    end=s.end,
                    extension_m=float(reach[s.peak]),
                    target=wrist[s.peak].copy(),
                )
            )
    return sorted(punches, key=lambda p: (p.peak, HANDS.index(p.hand)))


def frame_labels(punches: list[Punch], frames: int) -> np.ndarray:
    """The thesis's per-frame punch labels (§3.2).

    +1 from a punch's start to its peak inclusive, -1 after the peak to its end inclusive,
    0 elsewhere. Where two punches of one hand share a frame, the one with the later peak
    labels it.

    Args:
        punches: punches whose frames lie in [0, frames).
        frames: T, the clip's length.

    Returns:
        (T, 2) int8 labels, columns (left hand, right hand).
    """
    if not isinstance(frames, int | np.integer) or frames < 0:
        raise ValueError(f"frames must be a non-negative integer, got {frames!r}")
    labels = np.zeros((int(frames), len(HANDS)), dtype=np.int8)
    for p in sorted(punches, key=lambda p: p.peak):
        if p.end >= frames:
            raise ValueError(f"punch ends at frame {p.end}, outside a clip of {frames} frames")
        column = HANDS.index(p.hand)
        labels[p.start : p.peak + 1, column] = 1
        labels[p.peak + 1 : p.end + 1, column] = -1
    return labels


# --------------------------------------------------------------------------
# Steps
# --------------------------------------------------------------------------


def touch_downs(contacts: np.ndarray, min_off: int) -> np.ndarray:
    """The frames at which either foot lands after at least ``min_off`` frames off the floor,
    sorted; unlike `label_steps`, a landing whose lift-off the clip cut off counts, so that a
    rate measured over short clips is not biased low by their starts (a foot is in the air for
    a third of a walk).

    Args:
        contacts: (T, 2) bool (or 0/1), whether the (left, right) foot is on the floor.
        min_off: the shortest flight that counts; a foot off the floor at only the clip's
            first frames (an edge of the contact detector's speed window) does not.
    """
    c = np.asarray(contacts)
    if c.ndim != 2 or c.shape[1] != len(FEET) or not np.isin(c, (0, 1)).all():
        raise ValueError(
            f"contacts must be a bool (or 0/1) array of shape (T, 2) (left, right), got "
            f"{c.dtype} {c.shape}"
        )
    found = [
        stop
        for column in c.astype(bool).T
        for start, stop in runs(~column)
        if stop < len(column) and stop - start >= min_off
    ]
    return np.sort(np.asarray(found, dtype=int))


def label_steps(contacts: np.ndarray, feet: np.ndarray) -> list[Step]:
    """The steps of both feet: each time a foot's floor contact ends and later resumes.

    A foot already off the floor at the clip's first frame, or still off it at the last, is
    in a step the clip cuts off; those are not counted.

    Args:
        contacts: (T, 2) bool (or 0/1), whether the (left, right) foot is on the floor.
        feet: (T, 2, 3) world positions of the (left, right) foot, metres, z up.

    Returns:
        the steps, sorted by lift-off (then foot).
    """
    c = np.asarray(contacts)
    if c.ndim != 2 or c.shape[1] != len(FEET) or not np.isin(c, (0, 1)).all():
        raise ValueError(
            f"contacts must be a bool (or 0/1) array of shape (T, 2) (left, right), got "
            f"{c.dtype} {c.shape}"
        )
    c = c.astype(bool)
    f = np.asarray(feet, dtype=np.float64)
    if f.shape != (len(c), len(FEET), 3):
        raise ValueError(
            f"feet must have shape (T, 2, 3) = ({len(c)}, 2, 3) to match contacts, got {f.shape}"
        )
    steps = []
    for column, foot in enumerate(FEET):
        down = c[:, column].astype(np.int8)
        change = np.diff(down)
        lifts = np.flatnonzero(change == -1) + 1  # first frame off the floor
        lands = np.flatnonzero(change == 1) + 1  # first frame back on it
        for lift in lifts:
            later = lands[lands > lift]
            if len(later) == 0:
                break
            land = int(later[0])
            length = float(np.linalg.norm(f[land, column, :2] - f[lift - 1, column, :2]))
            if not math.isfinite(length):
                raise ValueError(f"feet must be finite at frames {lift - 1} and {land}")
            steps.append(Step(foot, int(lift), land, length))
    return sorted(steps, key=lambda s: (s.lift_off, FEET.index(s.foot)))
