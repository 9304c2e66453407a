"""The punch labeller scored on a labelled set whose true punches are known by construction
(`tests/punch_set.py`): DeepMimic's punch, mirrored, re-timed, doubled, on a smaller body, with
noise, and spliced into walking, running and the walker's turns; and walking, running, turning,
kicking and raising a guard with no punch.

A found punch matches a true one of the same hand when their peaks (full extensions) are at
most TOLERANCE frames apart, one to one. Run with -s to see the figures.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import mujoco
import numpy as np
import pytest
from punch_set import (
    FADE,
    PUNCH_FROM,
    RATE,
    LabelledClip,
    TruePunch,
    arm_slots,
    build,
    chain,
    match,
    mirror_keypoints,
    mirror_qpos,
    reach,
    score,
    splice_arm,
)

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.compiled import keypoint_positions
from models.humanoid.kinematics import heading_frame, heading_yaw
from models.pose.types import BLAZEPOSE_33
from tasks import deepmimic
from tasks.dataset.config import PunchConfig
from tasks.dataset.labels import Punch, label_punches

TOLERANCE = 3  # frames at 30 Hz: 0.1 s
# Measured on the set (71 true punches, 79 found, all 71 matched; the 8 others are on the
# kick): precision 0.899, recall 1.000. The thresholds allow one more false punch and one
# missed punch.
MIN_PRECISION = 0.88
MIN_RECALL = 0.98
# Measured: 62 of the 63 matches whose true kind is known are straights, as they should be
# (one 4 mm noisy copy of the smaller body's walking punch is called a hook).
MAX_WRONG_KINDS = 2
J = {name: i for i, name in enumerate(BLAZEPOSE_33)}
ARMS = [
    J[f"{side}_{part}"] for side in ("left", "right") for part in ("shoulder", "elbow", "wrist")
]


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(boxer_mjcf(BoneLengths()))


@pytest.fixture(scope="module")
def motion(assets: Path):
    cache: dict[str, np.ndarray] = {}

    def get(name: str) -> np.ndarray:
        if name not in cache:
            clip = deepmimic.load_deepmimic(deepmimic.clip_path(assets, name))
            cache[name] = deepmimic.retarget(clip)
        return cache[name]

    return get


@pytest.fixture(scope="module")
def labelled(assets: Path) -> list[tuple[LabelledClip, list[Punch]]]:
    return [
        (clip, label_punches(clip.keypoints, clip.root_quat, RATE, PunchConfig()))
        for clip in build(assets)
    ]


# --------------------------------------------------------------------------
# The clips and the construction
# --------------------------------------------------------------------------


def test_walker_clips_are_humanoid3d_walks_that_turn(assets: Path, motion):
    # The walker's clips have the humanoid3d clips' layout (44 numbers a frame, unit
    # quaternions, knees bending back and elbows forward), fit our joint limits and turn as
    # named.
    turns_deg = {
        "walker_forward": 0.0,
        "walker_turn_left0": 30.0,
        "walker_turn_left1": 56.0,
        "walker_turn_right0": -99.0,
        "walker_turn_right1": -53.0,
    }
    assert set(turns_deg) == set(deepmimic.WALKER_CLIPS)
    for name, turn in turns_deg.items():
        path = deepmimic.clip_path(assets, name)
        assert path.parent == assets / deepmimic.MOTIONS_DIR / "walker"
        clip = deepmimic.load_deepmimic(path)
        assert clip.num_frames == 38 and np.allclose(clip.dt, 1 / 30), name
        assert dict(clip.renormalised) == {}, name
        assert all(clip.joint_angles[k].max() < 0 for k in ("left_knee", "right_knee")), name
        assert all(clip.joint_angles[k].min() > 0 for k in ("left_elbow", "right_elbow")), name
        report = deepmimic.retarget_report(clip)
        # The joint limits move no body by more than a degree (turn_right0's right foot: 0.7).
        assert max(report.rotation_error_deg.values(), default=0.0) < 1.0, name
        yaw = np.degrees(heading_yaw(report.qpos[:, 3:7]))
        assert yaw[-1] - yaw[0] == pytest.approx(turn, abs=4.0), name
        assert np.linalg.norm(report.qpos[-1, :2] - report.qpos[0, :2]) > 0.7, name


def test_mirrored_motion_is_the_mirror_image(model, motion):
    qpos = motion("punch")
    keypoints = keypoint_positions(model, qpos)
    mirrored = keypoint_positions(model, mirror_qpos(qpos))
    assert np.allclose(mirrored, mirror_keypoints(keypoints), atol=1e-9)
    assert np.allclose(mirror_qpos(mirror_qpos(qpos)), qpos)
    assert reach(mirrored, "left") == pytest.approx(reach(keypoints, "right"))


def test_a_spliced_arm_moves_as_in_its_source_and_the_body_keeps_walking(model, motion):
    walk, punch = chain([motion("walk")] * 3), motion("punch")
    source, at = punch[PUNCH_FROM:], 20
    spliced = splice_arm(walk, source, "right", at)
    inside = np.arange(at, at + len(source))
    others = np.setdiff1d(np.arange(spliced.shape[1]), arm_slots("right"))
    assert np.array_equal(spliced[:, others], walk[:, others])
    outside = np.setdiff1d(np.arange(len(walk)), inside)
    assert np.array_equal(spliced[outside], walk[outside])
    # Between the fades: the source's reach, and its arm where the body faces.
    middle = slice(FADE, len(source) - FADE)
    k, s = keypoint_positions(model, spliced)[inside], keypoint_positions(model, source)
    assert np.allclose(reach(k, "right")[middle], reach(s, "right")[middle], atol=1e-9)

    def arm_in_heading(keypoints, quat):
        arm = keypoints[:, J["right_wrist"]] - keypoints[:, J["right_shoulder"]]
        return np.einsum("tji,tj->ti", heading_frame(quat), arm)

    got = arm_in_heading(k, spliced[inside, 3:7])
    want = arm_in_heading(s, np.repeat(source[:1, 3:7], len(source), axis=0))
    assert np.allclose(got[middle], want[middle], atol=1e-9)


def test_chained_clips_move_on_smoothly(model, motion):
    parts = [motion(name) for name in deepmimic.WALKER_CLIPS]
    tour = chain(parts)
    assert len(tour) == sum(map(len, parts)) - FADE * (len(parts) - 1)

    def largest_arm_step(qpos):
        k = keypoint_positions(model, qpos)[:, ARMS]
        return np.linalg.norm(np.diff(k, axis=0), axis=-1).max()

    # 0.105 m a frame against the parts' 0.085 at most: the cross-fades make no jump.
    assert largest_arm_step(tour) <= 1.3 * max(map(largest_arm_step, parts))
    yaw = np.degrees(np.unwrap(heading_yaw(tour[:, 3:7])))
    assert yaw[-1] - yaw[0] == pytest.approx(30 - 53 + 56 - 99, abs=8.0)


# --------------------------------------------------------------------------
# The score
# --------------------------------------------------------------------------


def false_and_missed(clip: LabelledClip, found: list[Punch]) -> tuple[int, int]:
    pairs = match(found, clip.punches, TOLERANCE)
    return len(found) - len(pairs), len(clip.punches) - len(pairs)


def test_no_punches_in_walking_running_turning_or_raising_a_guard(labelled):
    found_by_family: Counter[str] = Counter()
    for clip, found in labelled:
        if not clip.punches:
            found_by_family[clip.family] += len(found)
            if clip.family != "kick":
                assert found == [], clip.name
    counts = {
        f: sum(1 for c, _ in labelled if not c.punches and c.family == f) for f in found_by_family
    }
    print(f"\nnegative clips -> punches found: {dict(counts)} -> {dict(found_by_family)}")


def test_precision_and_recall_over_the_set(labelled):
    total = score(labelled, TOLERANCE)
    negatives = score([(c, f) for c, f in labelled if not c.punches], TOLERANCE)
    errors = [
        found[j].peak - clip.punches[i].peak
        for clip, found in labelled
        for i, j in match(found, clip.punches, TOLERANCE)
    ]
    print(
        f"\n{len(labelled)} clips, {sum(len(c.keypoints) for c, _ in labelled)} frames: "
        f"{total.true} true punches, {total.found} found, {total.matched} matched "
        f"(same hand, peaks within {TOLERANCE} frames): precision {total.precision:.3f}, "
        f"recall {total.recall:.3f}; peak error mean {np.mean(np.abs(errors)):.2f} frames, "
        f"largest {np.max(np.abs(errors))}; on the negatives {negatives.found} found"
    )
    for family in ("punch", "walk", "run", "walker", "kick"):
        part = score([(c, f) for c, f in labelled if c.family == family], TOLERANCE)
        print(
            f"  {family:7s} true {part.true:3d} found {part.found:3d} matched {part.matched:3d} "
            f"precision {part.precision:.3f} recall {part.recall:.3f}"
        )
    for clip, found in labelled:
        false, missed = false_and_missed(clip, found)
        if false or missed:
            print(f"  {clip.name}: {false} false, {missed} missed")
    assert total.precision >= MIN_PRECISION and total.recall >= MIN_RECALL
    # Every false punch is on the kick, whose arms swing up and across as the body spins 150
    # degrees: the labeller's one known confusion on this set. Without it, precision is 1.
    no_kick = score([(c, f) for c, f in labelled if c.family != "kick"], TOLERANCE)
    print(f"  without the kick: precision {no_kick.precision:.3f}, recall {no_kick.recall:.3f}")
    assert no_kick.precision == 1.0


def test_matched_punches_have_the_true_hand_and_kind(labelled):
    total = score(labelled, TOLERANCE)
    print(f"\nkinds: {total.kind_matched} of {total.kind_checked} known kinds right")
    assert total.kind_checked >= 60
    assert total.kind_matched >= total.kind_checked - MAX_WRONG_KINDS
    # No true punch is (also) found on the other hand near its peak.
    for clip, found in labelled:
        for true in clip.punches:
            assert not any(
                p.hand != true.hand and abs(p.peak - true.peak) <= TOLERANCE for p in found
            ), clip.name


def test_scoring_matches_one_to_one_by_hand_and_peak():
    def found(hand: str, peak: int) -> Punch:
        return Punch(hand, "straight", max(0, peak - 3), peak, peak + 5, 0.5, np.zeros(3))

    truth = [TruePunch("right", 10), TruePunch("right", 14)]
    labelled = [found("right", 12), found("right", 13), found("left", 10), found("right", 30)]
    # 13 is nearer 14 than 12 is, and 12 is then left to 10; the left one and 30 match nothing.
    assert match(labelled, truth, 3) == [(0, 0), (1, 1)]
    clip = LabelledClip("case", "punch", np.zeros((40, 33, 3)), np.zeros((40, 4)), tuple(truth))
    counts = score([(clip, labelled)], 3)
    assert (counts.true, counts.found, counts.matched) == (2, 4, 2)
    assert (counts.precision, counts.recall) == (0.5, 1.0)
