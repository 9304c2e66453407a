"""Punch labels, steps and fighter statistics of the dataset stage."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.compiled import keypoint_positions
from models.pose.types import BLAZEPOSE_33
from tasks import deepmimic
from tasks.dataset.config import THESIS_ARM_M, PunchConfig
from tasks.dataset.labels import (
    Punch,
    Step,
    arm_length,
    frame_labels,
    label_punches,
    label_steps,
    touch_downs,
)
from tasks.dataset.statistics import DISTRIBUTIONS, FighterStatistics, combine, fighter_statistics

J = {name: i for i, name in enumerate(BLAZEPOSE_33)}
RATE = deepmimic.FPS  # 30 Hz, the retargeted clips' rate
ARM = 0.33 + 0.26  # default BoneLengths: upper arm plus forearm
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(boxer_mjcf(BoneLengths()))


@pytest.fixture(scope="module")
def motions(assets: Path, model) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Clip name -> (qpos (T, 35), BlazePose keypoints (T, 33, 3)) of the retargeted clips."""
    out = {}
    for name in ("punch", "walk", "run", *deepmimic.WALKER_CLIPS):
        qpos = deepmimic.retarget(deepmimic.load_deepmimic(deepmimic.clip_path(assets, name)))
        out[name] = (qpos, keypoint_positions(model, qpos))
    return out


def noisy(keypoints: np.ndarray, sigma: float, seed: int) -> np.ndarray:
    return keypoints + np.random.default_rng(seed).normal(0.0, sigma, keypoints.shape)


# --------------------------------------------------------------------------
# DeepMimic clips
# --------------------------------------------------------------------------


def reach(keypoints: np.ndarray, hand: str) -> np.ndarray:
    """(T,) shoulder-wrist distance of one hand."""
    return np.linalg.norm(
        keypoints[:, J[f"{hand}_wrist"]] - keypoints[:, J[f"{hand}_shoulder"]], axis=1
    )


def speed_profile_stroke(distance: np.ndarray, rate: float, fraction: float = 0.1):
    """(start, peak, end) of the fastest reach, from the wrist's speed along the arm.

    The reach is where that speed is highest; the retraction where it is most negative
    after. Start and peak are where the reach's speed is within `fraction` of zero before
    and after its maximum, the end where the retraction's speed is back within `fraction`
    of zero.
    """
    speed = np.gradient(distance) * rate
    out = int(np.argmax(speed))
    back = out + int(np.argmin(speed[out:]))
    slow_out = speed <= fraction * speed[out]
    start = int(np.flatnonzero(slow_out[:out])[-1])
    peak = out + int(np.flatnonzero(slow_out[out:])[0])
    end = back + int(np.flatnonzero(speed[back:] >= fraction * speed[back])[0])
    return start, peak, end


def test_deepmimic_punch_is_one_right_straight(motions):
    qpos, keypoints = motions["punch"]
    # How many punches the clip holds, from the arms alone: the right shoulder-wrist distance
    # rises once by more than 0.3 m (0.24 m at frame 22 to 0.58 m at frame 26, held to frame 46,
    # back to 0.27 m by frame 56); the left one never rises 0.1 m above its lowest so far (the
    # left hand only comes up from hanging, 0.52 m, to a guard, 0.29-0.38 m). So: one punch,
    # thrown with the right hand, and none with the left.
    rises = {
        hand: reach(keypoints, hand) - np.minimum.accumulate(reach(keypoints, hand))
        for hand in ("left", "right")
    }
    assert rises["right"].max() > 0.3 and rises["left"].max() < 0.1

    punches = label_punches(keypoints, qpos[:, 3:7], RATE, PunchConfig())
    assert len(punches) == 1
    (punch,) = punches
    assert (punch.hand, punch.kind) == ("right", "straight")

    start, peak, end = speed_profile_stroke(reach(keypoints, "right"), RATE)
    assert (start, peak, end) == (21, 26, 55)  # the reference itself, for the record
    assert (
        abs(punch.start - start) <= 2 and abs(punch.peak - peak) <= 2 and abs(punch.end - end) <= 2
    )
    assert punch.extension_m == pytest.approx(reach(keypoints, "right")[punch.peak])
    assert np.allclose(punch.target, keypoints[punch.peak, J["right_wrist"]])

    # A few millimetres of noise, or a smaller fighter (thresholds follow the arm), change
    # neither the count nor the frames by much.
    for seed in range(3):
        (again,) = label_punches(noisy(keypoints, 0.004, seed), qpos[:, 3:7], RATE, PunchConfig())
        assert again.hand == "right"
        assert (
            abs(again.start - start) <= 2
            and abs(again.peak - peak) <= 2
            and abs(again.end - end) <= 2
        )
    smaller = keypoints * 0.8
    assert arm_length(smaller) == pytest.approx(0.8 * ARM)
    (scaled,) = label_punches(smaller, qpos[:, 3:7], RATE, PunchConfig())
    assert (scaled.hand, scaled.start, scaled.peak, scaled.end) == (
        "right",
        punch.start,
        punch.peak,
        punch.end,
    )


@pytest.mark.parametrize("name", ["walk", "run", *deepmimic.WALKER_CLIPS])
def test_no_punches_when_walking_running_or_turning(motions, name):
    # The walker's clips: a straight walk, and walks turning 30 and 56 degrees left and 99 and
    # 53 degrees right, the arms swinging as the body turns.
    qpos, keypoints = motions[name]
    assert label_punches(keypoints, qpos[:, 3:7], RATE, PunchConfig()) == []
    for seed in range(3):
        assert label_punches(noisy(keypoints, 0.004, seed), qpos[:, 3:7], RATE, PunchConfig()) == []


def test_arm_length_is_upper_arm_plus_forearm(model):
    keypoints = keypoint_positions(model, model.qpos0[None].repeat(4, axis=0))
    assert arm_length(keypoints) == pytest.approx(ARM)


# --------------------------------------------------------------------------
# Hand-built punches
# --------------------------------------------------------------------------

REST, OUT, HOLD, BACK = 12, 6, 3, 8  # frames of each phase of a synthetic punch


def min_jerk(u: np.ndarray) -> np.ndarray:
    return 10 * u**3 - 15 * u**4 + 6 * u**5


def progress() -> np.ndarray:
    """(T,) how far along its path the wrist is: rest, out, hold, back, rest."""
    return np.concatenate(
        [
            np.zeros(REST),
            min_jerk(np.arange(1, OUT + 1) / OUT),
            np.ones(HOLD),
            min_jerk(1 - np.arange(1, BACK + 1) / BACK),
            np.zeros(REST),
        ]
    )


def straight(u: np.ndarray) -> np.ndarray:
    """Right wrist relative to its shoulder: from a guard (0.29 m) forward to 0.56 m."""
    guard, extended = np.array([0.25, 0.12, 0.10]), np.array([0.55, 0.08, 0.08])
    return guard + u[:, None] * (extended - guard)


def hook(u: np.ndarray) -> np.ndarray:
    """A quarter circle around the shoulder from its right side to straight ahead, its radius
    growing from 0.3 to 0.5 m: more forward than sideways overall, but bowed."""
    angle = np.radians(-90 + 90 * u)
    radius = 0.30 + 0.20 * u
    return np.stack([radius * np.cos(angle), radius * np.sin(angle), 0.05 + 0 * u], axis=1)


def sweep(u: np.ndarray) -> np.ndarray:
    """A straight line across the body, twice as far sideways (left) as forward."""
    out, across = np.array([0.25, -0.05, 0.05]), np.array([0.45, 0.35, 0.05])
    return out + u[:, None] * (across - out)


def uppercut(u: np.ndarray) -> np.ndarray:
    """From chest height, 0.25 m below the shoulder, up to 0.22 m above it, barely forward."""
    low, high = np.array([0.20, 0.10, -0.25]), np.array([0.28, 0.10, 0.22])
    return low + u[:, None] * (high - low)


def body_with_right_wrist(model, offsets: np.ndarray) -> np.ndarray:
    """(T, 33, 3): the boxer standing still, its right wrist at its shoulder plus `offsets`."""
    keypoints = keypoint_positions(model, model.qpos0[None].repeat(len(offsets), axis=0))
    keypoints[:, J["right_wrist"]] = keypoints[:, J["right_shoulder"]] + offsets
    return keypoints


def quats(frames: int) -> np.ndarray:
    return np.tile(IDENTITY, (frames, 1))


@pytest.mark.parametrize(
    "kind, path",
    [("straight", straight), ("hook", hook), ("hook", sweep), ("uppercut", uppercut)],
    ids=["straight", "hook", "sweep", "uppercut"],
)
def test_synthetic_punches_are_found_and_classified(model, kind, path):
    u = progress()
    keypoints = body_with_right_wrist(model, path(u))
    punches = label_punches(keypoints, quats(len(u)), RATE, PunchConfig(), arm_m=ARM)
    assert [(p.hand, p.kind) for p in punches] == [("right", kind)]
    (punch,) = punches
    # Rest ends at frame REST - 1, full extension is reached at REST + OUT - 1, and the wrist
    # is back at rest at REST + OUT + HOLD + BACK - 1.
    assert abs(punch.start - (REST - 1)) <= 1
    assert abs(punch.peak - (REST + OUT - 1)) <= 1
    assert abs(punch.end - (REST + OUT + HOLD + BACK - 1)) <= 1
    for seed in range(5):
        again = label_punches(
            noisy(keypoints, 0.003, seed), quats(len(u)), RATE, PunchConfig(), arm_m=ARM
        )
        assert [(p.hand, p.kind) for p in again] == [("right", kind)], seed
    # The same punch thrown facing another way (the whole body turned 120 degrees about z).
    yaw = np.radians(120)
    turn = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    facing = np.tile([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)], (len(u), 1))
    (turned,) = label_punches(keypoints @ turn.T, facing, RATE, PunchConfig(), arm_m=ARM)
    assert (turned.kind, turned.start, turned.peak, turned.end) == (
        kind,
        punch.start,
        punch.peak,
        punch.end,
    )


def test_two_punches_in_a_row_are_two(model):
    u = np.concatenate([progress(), progress()])
    keypoints = body_with_right_wrist(model, straight(u))
    punches = label_punches(keypoints, quats(len(u)), RATE, PunchConfig(), arm_m=ARM)
    assert [p.peak for p in punches] == [REST + OUT - 1, len(progress()) + REST + OUT - 1]


def test_thresholds_scale_with_the_arm(model):
    # A straight whose reach grows by 0.15 m: under the thesis's 0.19 m for its 0.63 m arm,
    # over the 0.136 m that threshold becomes for a 0.45 m arm.
    guard, extended = np.array([0.38, 0.08, 0.05]), np.array([0.53, 0.08, 0.05])
    u = progress()
    keypoints = body_with_right_wrist(model, guard + u[:, None] * (extended - guard))
    growth = np.ptp(reach(keypoints, "right"))
    assert 0.14 < growth < 0.16
    q = quats(len(u))
    assert label_punches(keypoints, q, RATE, PunchConfig(), arm_m=THESIS_ARM_M) == []
    assert len(label_punches(keypoints, q, RATE, PunchConfig(), arm_m=0.45)) == 1


GUARD = np.array([0.25, 0.12, 0.10])  # right wrist in front of the chin, from its shoulder


def moves(*poses_and_frames) -> np.ndarray:
    """(T, 3) right wrist offsets: from the guard, a smooth 8-frame move to each pose in turn,
    each then held for its number of frames."""
    ramp = min_jerk(np.arange(1, 9) / 8)[:, None]
    out, here = [np.tile(GUARD, (12, 1))], GUARD
    for pose, frames in poses_and_frames:
        pose = np.asarray(pose, dtype=float)
        out += [here + ramp * (pose - here), np.tile(pose, (frames, 1))]
        here = pose
    return np.concatenate(out)


@pytest.mark.parametrize(
    "offsets",
    [
        # Dropping the guard to let the arm hang in front (the reach grows by 0.27 m, but the
        # arm points 63 degrees down), then raising it back and keeping it up (the wrist rises
        # 0.6 m to above the shoulder, and stays there).
        moves(((0.25, 0.0, -0.50), 15), (GUARD, 20)),
        # Swinging the arm out and back at shoulder height (the reach grows by 0.22 m, but
        # behind him), and in again.
        moves(
            ((0.0, -0.45, 0.0), 0), ((-0.45, -0.25, 0.0), 5), ((0.0, -0.45, 0.0), 0), (GUARD, 12)
        ),
    ],
    ids=["guard down and up", "arm swung back"],
)
def test_arm_moves_that_are_not_punches(model, offsets):
    keypoints = body_with_right_wrist(model, offsets)
    assert np.ptp(reach(keypoints, "right")) > 0.2
    assert label_punches(keypoints, quats(len(offsets)), RATE, PunchConfig(), arm_m=ARM) == []


def test_a_long_held_extension_ends_one_window_after_it(model):
    # Held out 2 s, more than twice the window: the punch ends one window (13 frames at 30 Hz)
    # after the full extension, not at the retraction 60 frames later.
    offsets = moves(((0.55, 0.08, 0.08), 60), (GUARD, 12))
    keypoints = body_with_right_wrist(model, offsets)
    (punch,) = label_punches(keypoints, quats(len(offsets)), RATE, PunchConfig(), arm_m=ARM)
    assert abs(punch.peak - (12 + 8 - 1)) <= 1
    assert punch.end == punch.peak + 13
    # Held 0.5 s, it is followed to the end of its retraction.
    offsets = moves(((0.55, 0.08, 0.08), 15), (GUARD, 12))
    keypoints = body_with_right_wrist(model, offsets)
    (punch,) = label_punches(keypoints, quats(len(offsets)), RATE, PunchConfig(), arm_m=ARM)
    assert abs(punch.end - (12 + 8 + 15 + 8 - 1)) <= 1


def test_video_like_noise_makes_no_punches(motions):
    # 1.5 cm of noise on every keypoint, about what BlazePose's 3D keypoints carry: the held
    # punch is not split, and walking, running and turning still hold none.
    negatives = ("walk", "run", *deepmimic.WALKER_CLIPS)
    for name, count in (("punch", 1), *((name, 0) for name in negatives)):
        qpos, keypoints = motions[name]
        for seed in range(5):
            found = label_punches(noisy(keypoints, 0.015, seed), qpos[:, 3:7], RATE, PunchConfig())
            assert len(found) == count, (name, seed)


def test_label_punches_rejects_bad_input(model):
    keypoints = body_with_right_wrist(model, straight(progress()))
    q = quats(len(keypoints))
    with pytest.raises(ValueError, match="keypoints"):
        label_punches(keypoints[:, :17], q, RATE, PunchConfig())
    with pytest.raises(ValueError, match="root_quat"):
        label_punches(keypoints, q[1:], RATE, PunchConfig())
    with pytest.raises(ValueError, match="rate"):
        label_punches(keypoints, q, 0.0, PunchConfig())
    with pytest.raises(ValueError, match="arm_m"):
        label_punches(keypoints, q, RATE, PunchConfig(), arm_m=-0.5)


# --------------------------------------------------------------------------
# Frame labels and steps
# --------------------------------------------------------------------------


def punch(hand: str, start: int, peak: int, end: int, kind: str = "straight") -> Punch:
    return Punch(hand, kind, start, peak, end, 0.5, np.zeros(3))


def test_frame_labels_by_hand():
    punches = [punch("left", 1, 3, 5), punch("right", 4, 5, 8), punch("left", 5, 6, 7)]
    labels = frame_labels(punches, 10)
    assert labels.dtype == np.int8
    # Frame 5 ends the first left punch and starts the second: the later punch labels it.
    left = [0, 1, 1, 1, -1, 1, 1, -1, 0, 0]
    right = [0, 0, 0, 0, 1, 1, -1, -1, -1, 0]
    assert labels.tolist() == [list(row) for row in zip(left, right, strict=True)]
    assert frame_labels([], 3).tolist() == [[0, 0]] * 3
    with pytest.raises(ValueError, match="outside"):
        frame_labels(punches, 8)


def test_label_steps_by_hand():
    on, off = True, False
    left = [off, off, on, on, off, off, off, on, on, off, on, on]  # cut at the start
    right = [on, on, on, off, off, on, on, on, on, on, off, off]  # cut at the end
    contacts = np.array([left, right]).T
    feet = np.full((12, 2, 3), 9.0)  # in the air: never read
    feet[0:4, 0] = (0.0, 0.0, 0.05)
    feet[7:9, 0] = (0.3, 0.4, 0.05)  # 0.5 m from the last contact
    feet[10:12, 0] = (0.3, 0.7, 0.05)  # 0.3 m on
    feet[0:3, 1] = (0.5, -0.2, 0.05)
    feet[5:10, 1] = (0.62, -0.2, 0.30)  # 0.12 m on the floor plan, whatever the height
    steps = label_steps(contacts, feet)
    assert [(s.foot, s.lift_off, s.touch_down) for s in steps] == [
        ("right", 3, 5),
        ("left", 4, 7),
        ("left", 9, 10),
    ]
    assert [s.length_m for s in steps] == pytest.approx([0.12, 0.5, 0.3])
    assert label_steps(np.ones((5, 2), bool), np.zeros((5, 2, 3))) == []
    assert label_steps(contacts.astype(np.uint8), feet) == steps
    with pytest.raises(ValueError, match="contacts"):
        label_steps(contacts * 2, feet)
    with pytest.raises(ValueError, match="feet"):
        label_steps(contacts, feet[:, :, :2])


def test_touch_downs_count_landings_whose_lift_off_the_clip_cut():
    """The same contacts as above: the left foot's landing at 2, whose lift-off came before the
    clip, counts (label_steps leaves it out); a flight shorter than ``min_off`` does not, and
    the right foot, still in the air at the end, has not landed."""
    on, off = True, False
    left = [off, off, on, on, off, off, off, on, on, off, on, on]
    right = [on, on, on, off, off, on, on, on, on, on, off, off]
    contacts = np.array([left, right]).T
    assert touch_downs(contacts, 1).tolist() == [2, 5, 7, 10]
    assert touch_downs(contacts, 2).tolist() == [2, 5, 7]
    assert touch_downs(contacts, 3).tolist() == [7]
    assert touch_downs(np.ones((5, 2), bool), 1).tolist() == []
    with pytest.raises(ValueError, match="contacts"):
        touch_downs(contacts * 2, 1)


# --------------------------------------------------------------------------
# Fighter statistics
# --------------------------------------------------------------------------

FRAMES, STAT_RATE = 120, 60.0  # two seconds: 1/30 of a minute


def statistics_case():
    """A fighter standing at the origin facing +x, his opponent 2 m then 1.5 m behind him."""
    keypoints = np.zeros((FRAMES, 33, 3))
    keypoints[:, J["nose"], 2] = 1.6
    keypoints[:, J["left_wrist"], 2] = 1.5
    keypoints[:, J["right_wrist"], 2] = np.where(np.arange(FRAMES) < 60, 1.4, 1.6)
    keypoints[:, J["left_ankle"]] = (0.3, 0.1, 0.1)
    keypoints[90:, J["left_ankle"]] = (-0.3, 0.1, 0.1)  # the left foot leads backwards
    keypoints[:, J["right_ankle"]] = (0.0, -0.1, 0.1)
    root_pos = np.tile([0.0, 0.0, 1.0], (FRAMES, 1))
    root_quat = np.tile(IDENTITY, (FRAMES, 1))
    opponent = np.tile([-2.0, 0.0, 0.9], (FRAMES, 1))
    opponent[60:, 0] = -1.5
    punches = [
        punch("left", 10, 14, 22),
        punch("right", 30, 36, 48, kind="hook"),
        punch("left", 70, 75, 94, kind="uppercut"),
    ]
    steps = [Step("left", 20, 30, 0.3), Step("right", 80, 95, 0.5)]
    return punches, steps, keypoints, root_pos, root_quat, opponent


def test_fighter_statistics_by_hand():
    punches, steps, keypoints, root_pos, root_quat, opponent = statistics_case()
    common = dict(
        punches=punches,
        steps=steps,
        keypoints=keypoints,
        root_pos=root_pos,
        root_quat=root_quat,
        rate=STAT_RATE,
    )
    stats = fighter_statistics(opponent_root=opponent, **common)
    expected = {
        "minutes": 1 / 30,
        "punches_per_min": 90.0,  # 3 punches in 1/30 min
        "punches_per_min_left": 60.0,
        "punches_per_min_right": 30.0,
        "punches_per_min_straight": 30.0,
        "punches_per_min_hook": 30.0,
        "punches_per_min_uppercut": 30.0,
        "punch_duration_mean_s": 0.3,  # 12, 18 and 24 frames at 60 Hz
        "distance_mean_m": 1.75,  # 2 m, then 1.5 m, half the time each
        "guard_height_mean_m": -0.1,  # hands 0.15 m below the nose, then 0.05 m
        "steps_per_min": 60.0,
        "step_length_mean_m": 0.4,
        "orthodox_share": 0.25,  # towards the opponent (-x) the left foot leads in 30 frames
    }
    assert stats.scalars.keys() == expected.keys()
    assert stats.scalars == pytest.approx(expected)
    assert set(stats.distributions) == set(DISTRIBUTIONS)
    assert stats.distributions["punch_duration_s"] == pytest.approx([0.2, 0.3, 0.4])
    assert stats.distributions["step_length_m"] == pytest.approx([0.3, 0.5])
    assert stats.distributions["distance_m"] == pytest.approx([2.0] * 60 + [1.5] * 60)
    assert stats.distributions["guard_height_m"] == pytest.approx([-0.15] * 60 + [-0.05] * 60)

    # Without an opponent: no distance, and the lead foot is along the facing direction (+x).
    alone = fighter_statistics(opponent_root=None, **common)
    assert "distance_mean_m" not in alone.scalars and len(alone.distributions["distance_m"]) == 0
    assert alone.scalars["orthodox_share"] == pytest.approx(0.75)
    # Nothing to average: left out, not NaN.
    idle = fighter_statistics(**{**common, "punches": [], "steps": []}, opponent_root=None)
    assert "punch_duration_mean_s" not in idle.scalars and "step_length_mean_m" not in idle.scalars
    assert idle.scalars["punches_per_min"] == 0.0 and idle.scalars["steps_per_min"] == 0.0


def shifted(punch_or_step, by: int):
    if isinstance(punch_or_step, Punch):
        p = punch_or_step
        return Punch(p.hand, p.kind, p.start - by, p.peak - by, p.end - by, p.extension_m, p.target)
    s = punch_or_step
    return Step(s.foot, s.lift_off - by, s.touch_down - by, s.length_m)


def test_combining_halves_gives_the_whole():
    punches, steps, keypoints, root_pos, root_quat, opponent = statistics_case()
    whole = fighter_statistics(
        punches=punches,
        steps=steps,
        keypoints=keypoints,
        root_pos=root_pos,
        root_quat=root_quat,
        opponent_root=opponent,
        rate=STAT_RATE,
    )
    halves = []
    for lo, hi in ((0, 60), (60, FRAMES)):
        halves.append(
            fighter_statistics(
                punches=[shifted(p, lo) for p in punches if lo <= p.start and p.end < hi],
                steps=[shifted(s, lo) for s in steps if lo <= s.lift_off and s.touch_down < hi],
                keypoints=keypoints[lo:hi],
                root_pos=root_pos[lo:hi],
                root_quat=root_quat[lo:hi],
                opponent_root=opponent[lo:hi],
                rate=STAT_RATE,
            )
        )
    # The halves differ (2 punches then 1, 2 m then 1.5 m away), so a plain average of them
    # would not give the whole; per-punch means must weigh by count (0.25 s and 0.4 s -> 0.3 s).
    assert halves[0].scalars["punches_per_min"] != halves[1].scalars["punches_per_min"]
    assert halves[0].scalars["distance_mean_m"] != halves[1].scalars["distance_mean_m"]
    for merged in (combine(halves), combine(halves, [1.0, 1.0])):
        assert merged.scalars.keys() == whole.scalars.keys()
        assert merged.scalars == pytest.approx(whole.scalars)
        for name, samples in whole.distributions.items():
            assert merged.distributions[name] == pytest.approx(samples), name
    # A 1 s clip without an opponent or punches adds time to the rates (weighted by time: 3
    # punches in 3 s, not the mean of 90 and 0 per minute) but nothing to the distance.
    alone = fighter_statistics(
        punches=[],
        steps=[],
        keypoints=keypoints[:60],
        root_pos=root_pos[:60],
        root_quat=root_quat[:60],
        opponent_root=None,
        rate=STAT_RATE,
    )
    mixed = combine([whole, alone], [2.0, 1.0])
    assert mixed.scalars["minutes"] == pytest.approx(0.05)
    assert mixed.scalars["punches_per_min"] == pytest.approx(60.0)
    assert mixed.scalars["distance_mean_m"] == pytest.approx(1.75)
    assert mixed.scalars["guard_height_mean_m"] == pytest.approx((2 * -0.1 + 1 * -0.15) / 3)
    assert mixed.scalars["punch_duration_mean_s"] == pytest.approx(0.3)
    with pytest.raises(ValueError, match="durations_s"):
        combine(halves, [1.0, 2.0])
    with pytest.raises(ValueError, match="stats"):
        combine([])
    assert isinstance(mixed, FighterStatistics)


def test_fighter_statistics_rejects_bad_input():
    punches, steps, keypoints, root_pos, root_quat, opponent = statistics_case()
    common = dict(
        punches=punches,
        steps=steps,
        keypoints=keypoints,
        root_pos=root_pos,
        root_quat=root_quat,
        opponent_root=opponent,
        rate=STAT_RATE,
    )
    with pytest.raises(ValueError, match="rate"):
        fighter_statistics(**{**common, "rate": 0.0})
    with pytest.raises(ValueError, match="keypoints"):
        fighter_statistics(**{**common, "keypoints": keypoints[:, :17]})
    with pytest.raises(ValueError, match="root_pos"):
        fighter_statistics(**{**common, "root_pos": root_pos[:, :2]})
    with pytest.raises(ValueError, match="opponent_root"):
        fighter_statistics(**{**common, "opponent_root": opponent[1:]})
    with pytest.raises(ValueError, match="outside"):
        fighter_statistics(**{**common, "punches": [punch("left", 100, 110, FRAMES)]})
