"""A labelled set for the punch labeller (`tasks.dataset.labels.label_punches`): clips whose
true punches are known by construction, and the score of a labelling against them.

Every clip is built from DeepMimic clips retargeted onto our humanoid (`tasks.deepmimic`), at
30 Hz: the punch clip (one right straight), the walk, run and kick, and the walker's straight
walk and four turns.

- Positives: the punch clip as it is, mirrored (a left straight), on a smaller body, with
  keypoint noise, re-timed to 0.8 and 1.25 times its length, as a double punch whose first
  punch is not retracted far, and its punching arm spliced into walking (once, twice, with
  either hand), into the walker's turns and into running.
- Negatives: the walk, run, kick and walker clips, also chained into longer walks and runs
  (`chain`), with noise, on a smaller body, and the punch clip's other arm (a guard raised
  from hanging and dropped again) spliced into a walk.

A splice (`splice_arm`) gives the base clip's arm the source's motion relative to where the
body faces (`aimed_arm`: the DeepMimic punch turns the whole body, so its hinges alone would
not do), with a `FADE`-frame cross-fade at each end, so the arm comes from and goes back to
the base's swing while the rest of the body keeps walking. Between the fades the elbow angle,
and so the shoulder-wrist distance, is the source's exactly: a true punch's peak is where that
distance stops growing in the source (`full_extension`), moved to where the source was put.

Shape letters: T frames; qpos rows are the humanoid's 35 numbers (root position, root
quaternion w-x-y-z, 28 hinges).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.compiled import keypoint_positions
from models.humanoid.kinematics import (
    BODY_NAMES,
    JOINT_LAYOUT,
    axis_angle_matrix,
    body_rotations,
    heading_yaw,
    qpos_from_body_rotations,
    wrap_angle,
)
from models.pose.types import BLAZEPOSE_33
from tasks import deepmimic
from tasks.dataset.labels import Punch

RATE = deepmimic.FPS  # 30 Hz
FADE = 6  # frames of cross-fade at each end of a splice and between chained clips
# The part of the punch clip spliced: frames 10-64. The reach starts at 21 and is back at the
# guard by 56 (tests/test_dataset_labels.py), well clear of the fades (10-15 and 59-64).
PUNCH_FROM = 10
# A double punch from the punch clip (the whole body): out to full extension and held (26-46),
# back only to frame 50 (the reach 0.14 m shorter, less than the thesis's P, 0.18 m for our
# arm), out again to frame 46, and back to the guard.
DOUBLE_FRAMES = (*range(PUNCH_FROM, 51), *range(49, 45, -1), *range(46, 65))
SMALLER = 0.85  # the smaller body's bones, as a fraction of the default ones

_INDEX = {name: i for i, name in enumerate(BLAZEPOSE_33)}
_JOINTS = {joint.name: joint for joint in JOINT_LAYOUT}


@dataclass(frozen=True)
class TruePunch:
    """One punch a clip holds by construction: the hand, and the frame of full extension."""

    hand: str
    peak: int
    kind: str | None = "straight"  # None: not known by construction


@dataclass(frozen=True, eq=False)
class LabelledClip:
    """One clip of the set.

    Attributes:
        name: says how it was built.
        family: the motion it is mostly made of: punch, walk, run, kick or walker.
        keypoints: (T, 33, 3) BlazePose-order keypoints, world metres, z up.
        root_quat: (T, 4) pelvis quaternions (w, x, y, z).
        punches: its true punches; empty for a negative.
    """

    name: str
    family: str
    keypoints: np.ndarray
    root_quat: np.ndarray
    punches: tuple[TruePunch, ...]


# --------------------------------------------------------------------------
# Building motions
# --------------------------------------------------------------------------


def arm_slots(hand: str) -> list[int]:
    """qpos indices of one arm's hinges: the shoulder's three, then the elbow."""
    return [
        _JOINTS[f"{hand}_{part}"].qpos_start + k
        for part in ("shoulder", "elbow")
        for k in range(len(_JOINTS[f"{hand}_{part}"].hinges))
    ]


def mirror_qpos(qpos: np.ndarray) -> np.ndarray:
    """(T, 35) the motion mirrored in the plane y = 0 (the character's left and right swapped).

    A reflection M = diag(1, -1, 1) turns a rotation R into M R M: a rotation about x or z by
    the opposite angle, about y by the same. So the root's y and its quaternion's x and z
    change sign, and each hinge takes its mirror joint's angle, negated about x and z (knee
    and elbow hinges are about y).
    """
    q = np.asarray(qpos, dtype=np.float64)
    out = q.copy()
    out[:, 1] *= -1
    out[:, [4, 6]] *= -1
    swap = {"left": "right", "right": "left"}
    for joint in JOINT_LAYOUT:
        side, _, rest = joint.name.partition("_")
        other = _JOINTS[f"{swap[side]}_{rest}"] if side in swap else joint
        for k, hinge in enumerate(joint.hinges):
            sign = -1.0 if hinge.endswith(("_x", "_z")) else 1.0
            out[:, joint.qpos_start + k] = sign * q[:, other.qpos_start + k]
    return out


def mirror_keypoints(keypoints: np.ndarray) -> np.ndarray:
    """(T, 33, 3) keypoints mirrored in y = 0, left and right landmarks swapped."""
    swap = [
        _INDEX[name.replace("left", "@").replace("right", "left").replace("@", "right")]
        for name in BLAZEPOSE_33
    ]
    out = np.asarray(keypoints, dtype=np.float64)[:, swap].copy()
    out[..., 1] *= -1
    return out


def _ramp(frames: int) -> np.ndarray:
    """(frames,) smoothstep weights strictly between 0 and 1, rising."""
    u = np.arange(1, frames + 1) / (frames + 1)
    return u * u * (3 - 2 * u)


def _blend(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """qpos rows a and b (F, 35) mixed with weights w (F,) of b: root position linearly, root
    rotation by normalised linear interpolation, hinges along the shorter way round."""
    out = a + w[:, None] * (b - a)
    qa, qb = a[:, 3:7], b[:, 3:7] * np.sign(np.sum(a[:, 3:7] * b[:, 3:7], axis=1))[:, None]
    rot = qa + w[:, None] * (qb - qa)
    out[:, 3:7] = rot / np.linalg.norm(rot, axis=1, keepdims=True)
    out[:, 7:] = a[:, 7:] + w[:, None] * wrap_angle(b[:, 7:] - a[:, 7:])
    return out


def chain(parts: Sequence[np.ndarray], fade: int = FADE) -> np.ndarray:
    """Clips played one after another: each next one turned about z and moved on the floor so
    that its first frame faces and stands where the previous one's `fade`-th last frame does,
    and cross-faded with it over those `fade` frames.

    Returns:
        (sum of lengths - fade * (len(parts) - 1), 35) qpos.
    """
    out = np.asarray(parts[0], dtype=np.float64).copy()
    for part in parts[1:]:
        part = np.asarray(part, dtype=np.float64)
        ref = out[-fade]
        turn = float(heading_yaw(ref[3:7]) - heading_yaw(part[0, 3:7]))
        rot = Rotation.from_euler("z", turn)
        placed = part.copy()
        placed[:, :2] = (part[:, :2] - part[0, :2]) @ rot.as_matrix()[:2, :2].T + ref[:2]
        turned = rot * Rotation.from_quat(part[:, 3:7], scalar_first=True)
        placed[:, 3:7] = turned.as_quat(scalar_first=True)
        overlap = _blend(out[-fade:], placed[:fade], _ramp(fade))
        out = np.concatenate([out[:-fade], overlap, placed[fade:]])
    return out


def aimed_arm(base: np.ndarray, source: np.ndarray, hand: str) -> np.ndarray:
    """`base` with `hand`'s arm as `source` moves it relative to where it faces: the upper arm
    and forearm take the source's world rotations turned about z by the base's heading yaw
    less the source's first frame's, so that the shoulder-wrist vector in the base's heading
    frame is the source's in its first frame's heading frame, and the elbow angle is the
    source's.

    (The DeepMimic punch turns the whole body 110 degrees left and throws the arm out to the
    side of the pelvis, which ends up pointing where the body faced at the guard: its arm
    hinges alone, put on a walker who keeps facing ahead, would raise the arm sideways.)

    Args:
        base, source: (S, 35) qpos of the same length.

    Returns:
        (S, 35) qpos; only `hand`'s arm hinges differ from `base`.
    """
    turn = heading_yaw(base[:, 3:7]) - heading_yaw(source[0, 3:7])
    rot = body_rotations(base)
    source_rot = body_rotations(source)
    for part in ("upper_arm", "lower_arm", "hand"):
        b = BODY_NAMES.index(f"{hand}_{part}")
        rot[:, b] = axis_angle_matrix((0.0, 0.0, 1.0), turn) @ source_rot[:, b]
    out = base.copy()
    slots = arm_slots(hand)
    out[:, slots] = qpos_from_body_rotations(base[:, :3], rot)[:, slots]
    return out


def splice_arm(
    base: np.ndarray, source: np.ndarray, hand: str, at: int, fade: int = FADE
) -> np.ndarray:
    """`base` with `hand`'s arm moving as in `source` (`aimed_arm`) at frames at ..
    at + len(source) - 1, cross-faded from and back to the base's over the first and last
    `fade` of them.

    Returns:
        (T, 35) a new qpos; `base` is not changed.
    """
    base = np.asarray(base, dtype=np.float64)
    source = np.asarray(source, dtype=np.float64)
    if not 0 <= at <= len(base) - len(source):
        raise ValueError(f"at must put all {len(source)} frames of source in base, got {at}")
    here = base[at : at + len(source)]
    aimed = aimed_arm(here, source, hand)
    w = np.ones(len(source))
    w[:fade], w[-fade:] = _ramp(fade), _ramp(fade)[::-1]
    slots = arm_slots(hand)
    out = base.copy()
    out[at : at + len(source), slots] = here[:, slots] + w[:, None] * wrap_angle(
        aimed[:, slots] - here[:, slots]
    )
    return out


def reach(keypoints: np.ndarray, hand: str) -> np.ndarray:
    """(T,) shoulder-wrist distance of one hand."""
    wrist, shoulder = _INDEX[f"{hand}_wrist"], _INDEX[f"{hand}_shoulder"]
    return np.linalg.norm(keypoints[:, wrist] - keypoints[:, shoulder], axis=-1)


def full_extension(distance: np.ndarray, lo: int = 0, hi: int | None = None) -> int:
    """The reference full extension of the fastest reach in frames lo .. hi - 1: the first frame
    after the shoulder-wrist distance's fastest growth where it grows by less than a tenth of
    that (as `speed_profile_stroke` in tests/test_dataset_labels.py).
    """
    speed = np.diff(distance[lo:hi])  # speed[i]: frame lo + i to lo + i + 1
    fastest = int(np.argmax(speed))
    slow = np.flatnonzero(speed[fastest:] <= 0.1 * speed[fastest])
    return lo + fastest + int(slow[0])


# --------------------------------------------------------------------------
# The set
# --------------------------------------------------------------------------

NOISES = (0.0, 0.004, 0.015)  # keypoint noise, metres (standard deviation per coordinate)
SEEDS = (0, 1)  # noise seeds for each noisy version


@dataclass(frozen=True, eq=False)
class _Motions:
    """The retargeted clips for one body, and `add`, which puts a clip of them in the set."""

    assets: Path
    bones: BoneLengths
    model: mujoco.MjModel
    clips: list[LabelledClip]

    def motion(self, name: str, fps: float = RATE) -> np.ndarray:
        clip = deepmimic.load_deepmimic(deepmimic.clip_path(self.assets, name))
        return deepmimic.retarget(clip, self.bones, fps=fps)

    def peak(self, qpos: np.ndarray, lo: int = 0, hi: int | None = None) -> int:
        return full_extension(reach(keypoint_positions(self.model, qpos), "right"), lo, hi)

    def add(
        self,
        name: str,
        family: str,
        qpos: np.ndarray,
        punches: Sequence[TruePunch] = (),
        noises: Sequence[float] = (0.0,),
    ) -> None:
        """The clip as it is, and with each noise in `noises` (for each of SEEDS)."""
        keypoints = keypoint_positions(self.model, qpos)
        quat = qpos[:, 3:7].copy()
        for sigma in noises:
            for seed in SEEDS if sigma else (None,):
                noisy = keypoints
                tag = name
                if seed is not None:
                    rng = np.random.default_rng(seed)
                    noisy = keypoints + rng.normal(0.0, sigma, keypoints.shape)
                    tag = f"{name} +{sigma * 1000:g} mm #{seed}"
                self.clips.append(LabelledClip(tag, family, noisy, quat, tuple(punches)))


def _motions(assets: Path, scale: float, clips: list[LabelledClip]) -> _Motions:
    default = BoneLengths()
    bones = BoneLengths(**{f.name: getattr(default, f.name) * scale for f in fields(default)})
    return _Motions(assets, bones, mujoco.MjModel.from_xml_string(boxer_mjcf(bones)), clips)


def build(assets: str | Path) -> list[LabelledClip]:
    """The whole labelled set: 123 clips, 71 true punches, 9 863 frames (a quarter of a
    second to build)."""
    clips: list[LabelledClip] = []
    m = _motions(Path(assets), 1.0, clips)
    punch = m.motion("punch")
    peak = m.peak(punch)  # 26
    mirrored = mirror_qpos(punch)
    walk = chain([m.motion("walk")] * 3)  # 105 frames
    run = chain([m.motion("run")] * 4)  # 82 frames
    walker = [m.motion(name) for name in deepmimic.WALKER_CLIPS]
    forward, left0, left1, right0, right1 = walker
    tour = chain([forward, left0, right1, left1, right0])  # 166 frames, turning 4 times

    def spliced_punches(base: np.ndarray, *hands_at: tuple[str, int]):
        """`base` with a punch thrown by each (hand, frame the spliced part starts)."""
        qpos, truth = base, []
        for hand, at in hands_at:
            source = punch if hand == "right" else mirrored
            qpos = splice_arm(qpos, source[PUNCH_FROM:], hand, at)
            truth.append(TruePunch(hand, at + peak - PUNCH_FROM))
        return qpos, truth

    # Positives: the punch clip, then its arm in a walk, a run and the walker's turns.
    m.add("punch", "punch", punch, [TruePunch("right", peak)], NOISES)
    m.add("punch mirrored", "punch", mirrored, [TruePunch("left", peak)], NOISES)
    m.add("walk + right punch", "walk", *spliced_punches(walk, ("right", 20)), NOISES)
    m.add("walk + left punch", "walk", *spliced_punches(walk, ("left", 40)), NOISES)
    two = spliced_punches(chain([m.motion("walk")] * 4), ("right", 10), ("right", 70))
    m.add("walk + two right punches", "walk", *two, NOISES[:2])
    turning = spliced_punches(tour, ("right", 30), ("left", 70))
    m.add("walker tour + right and left punch", "walker", *turning, NOISES)
    m.add("run + right punch", "run", *spliced_punches(run, ("right", 15)), NOISES[:2])
    for stretch in (0.8, 1.25):  # the punch taking 0.8 and 1.25 times as long
        timed = m.motion("punch", fps=RATE * stretch)
        timed_peak = m.peak(timed)
        m.add(f"punch x{stretch:g} time", "punch", timed, [TruePunch("right", timed_peak)])
        start = round(PUNCH_FROM * stretch)
        qpos = splice_arm(walk, timed[start:], "right", 15)
        truth = [TruePunch("right", 15 + timed_peak - start)]
        m.add(f"walk + right punch x{stretch:g} time", "walk", qpos, truth, NOISES[:2])
    # The double punch's second is the first's retraction played backwards: its path, and so
    # its kind, is not known by construction.
    double = punch[list(DOUBLE_FRAMES)]
    low = DOUBLE_FRAMES.index(50)  # the first punch retracted as far as it goes
    peaks = (m.peak(double, 0, low + 1), m.peak(double, low))
    truth = [TruePunch("right", peaks[0]), TruePunch("right", peaks[1], None)]
    m.add("double punch", "punch", double, truth, NOISES)
    truth = [replace(t, peak=25 + t.peak) for t in truth]
    m.add("walk + double punch", "walk", splice_arm(walk, double, "right", 25), truth, NOISES[:2])

    # Negatives: walking, running, turning, kicking, and a guard raised and dropped.
    for name in ("walk", "run", "kick"):
        m.add(name, name, m.motion(name), (), NOISES)
    for name, qpos in zip(deepmimic.WALKER_CLIPS, walker, strict=True):
        m.add(name, "walker", qpos, (), NOISES)
    m.add("walk x3", "walk", walk, (), NOISES)
    m.add("run x4", "run", run, (), NOISES)
    m.add("walker tour", "walker", tour, (), NOISES)
    # The punch clip's left arm only raises a guard from hanging (0.52 m) to 0.29-0.38 m.
    for hand, source in (("left", punch), ("right", mirrored)):
        qpos = splice_arm(walk, source[PUNCH_FROM:], hand, 30)
        m.add(f"walk + {hand} guard raised and dropped", "walk", qpos, (), NOISES)

    # A smaller fighter: thresholds follow the arm.
    small = _motions(Path(assets), SMALLER, clips)
    punch = small.motion("punch")
    walk = chain([small.motion("walk")] * 3)
    tag = f"(body x{SMALLER:g})"
    small.add(f"punch {tag}", "punch", punch, [TruePunch("right", small.peak(punch))], NOISES)
    small.add(f"walk {tag}", "walk", walk, (), NOISES[:2])
    at = 20
    truth = [TruePunch("right", at + small.peak(punch) - PUNCH_FROM)]
    qpos = splice_arm(walk, punch[PUNCH_FROM:], "right", at)
    small.add(f"walk + right punch {tag}", "walk", qpos, truth, NOISES[:2])
    return clips


# --------------------------------------------------------------------------
# Scoring
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Score:
    """Counts over a set of clips.

    Attributes:
        true: true punches.
        found: punches the labeller found.
        matched: found punches matched to a true one (same hand, peaks within the tolerance).
        kind_checked: matched ones whose true kind is known.
        kind_matched: of those, the ones whose kind is the true one.
    """

    true: int
    found: int
    matched: int
    kind_checked: int
    kind_matched: int

    @property
    def precision(self) -> float:
        return self.matched / self.found if self.found else 1.0

    @property
    def recall(self) -> float:
        return self.matched / self.true if self.true else 1.0


def match(
    found: Sequence[Punch], truth: Sequence[TruePunch], tolerance: int
) -> list[tuple[int, int]]:
    """One-to-one pairs (truth index, found index) of the same hand whose peaks are at most
    `tolerance` frames apart, closest pairs first."""
    candidates = sorted(
        (abs(f.peak - t.peak), i, j)
        for i, t in enumerate(truth)
        for j, f in enumerate(found)
        if f.hand == t.hand and abs(f.peak - t.peak) <= tolerance
    )
    pairs, used_true, used_found = [], set(), set()
    for _, i, j in candidates:
        if i not in used_true and j not in used_found:
            pairs.append((i, j))
            used_true.add(i)
            used_found.add(j)
    return sorted(pairs)


def score(labelled: Iterable[tuple[LabelledClip, Sequence[Punch]]], tolerance: int) -> Score:
    """The counts over (clip, the labeller's punches on it) pairs."""
    true = found = matched = kind_checked = kind_matched = 0
    for clip, punches in labelled:
        pairs = match(punches, clip.punches, tolerance)
        true += len(clip.punches)
        found += len(punches)
        matched += len(pairs)
        known = [(clip.punches[i].kind, punches[j].kind) for i, j in pairs]
        known = [(want, got) for want, got in known if want is not None]
        kind_checked += len(known)
        kind_matched += sum(want == got for want, got in known)
    return Score(true, found, matched, kind_checked, kind_matched)
