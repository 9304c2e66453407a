"""Synthetic ground truth for the lift (DeepMimic clips on our humanoid) and the lift's metrics."""

from __future__ import annotations

import json
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from models.humanoid.boxer import JOINT_RANGES_DEG, BoneLengths, boxer_mjcf
from models.humanoid.kinematics import HINGE_NAMES, axis_angle_matrix, body_rotations
from models.pose.types import BLAZEPOSE_33
from tasks import deepmimic
from tasks.errors import BadInput
from tasks.lift import metrics
from tasks.lift import synthetic as syn
from tasks.lift.camera import look_at, project

WRISTS = [BLAZEPOSE_33.index("left_wrist"), BLAZEPOSE_33.index("right_wrist")]
SOLE_SITES = [
    BLAZEPOSE_33.index(n)
    for n in ("left_heel", "right_heel", "left_foot_index", "right_foot_index")
]


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(boxer_mjcf(BoneLengths()))


@pytest.fixture(scope="module")
def clips(assets: Path) -> dict[str, deepmimic.DeepMimicClip]:
    return {
        name: deepmimic.load_deepmimic(deepmimic.clip_path(assets, name))
        for name in deepmimic.CLIPS
    }


@pytest.fixture(scope="module")
def retargeted(clips) -> dict[str, deepmimic.Retargeted]:
    return {name: deepmimic.retarget_report(clip) for name, clip in clips.items()}


# --------------------------------------------------------------------------
# DeepMimic clips and retargeting
# --------------------------------------------------------------------------


def test_clips_load_as_documented(clips):
    for name, clip in clips.items():
        assert clip.frames.shape[1] == deepmimic.FRAME_WIDTH == 44, name
        assert np.allclose(clip.dt[:-1], 1 / 30, atol=1e-5) and clip.dt[-1] == 0, name
        assert np.allclose(np.linalg.norm(clip.root_quat, axis=1), 1.0), name
        # y up: the pelvis stands 0.7-0.95 m above DeepMimic's floor.
        assert clip.root_pos[:, 1].min() > 0.65 and clip.root_pos[:, 1].max() < 0.95, name
        # Knees only flex one way (negative about z), elbows the other.
        for side in ("left", "right"):
            assert (clip.joint_angles[f"{side}_knee"] < 0.01).all(), name
            assert (clip.joint_angles[f"{side}_elbow"] > -0.01).all(), name
    assert dict(clips["kick"].renormalised) == {"right_hip": 20, "right_ankle": 9}
    assert dict(clips["walk"].renormalised) == {}


def test_bad_files_are_named(tmp_path: Path):
    missing = tmp_path / "nope.txt"
    with pytest.raises(BadInput, match="nope.txt"):
        deepmimic.load_deepmimic(missing)
    garbled = tmp_path / "garbled.txt"
    garbled.write_text("{not json")
    with pytest.raises(BadInput, match="garbled.txt.*JSON"):
        deepmimic.load_deepmimic(garbled)
    short = tmp_path / "short.txt"
    short.write_text(json.dumps({"Loop": "none", "Frames": [[0.03] * 40, [0.0] * 40]}))
    with pytest.raises(BadInput, match="short.txt.*44"):
        deepmimic.load_deepmimic(short)
    with pytest.raises(ValueError, match="clip_name"):
        deepmimic.clip_path(tmp_path, "dance")


def test_retargets_to_30_hz_feet_on_the_floor(clips, retargeted, model):
    for name, result in retargeted.items():
        qpos = result.qpos
        assert result.fps == 30.0
        assert qpos.shape == (clips[name].num_frames, 35), name  # the clips are 30 Hz already
        assert np.isfinite(qpos).all(), name
        points = syn.truth_points(model, qpos)
        assert points.shape == (len(qpos), 33, 3) and np.isfinite(points).all()
        # The foot boxes (what touches MuJoCo's floor) rest on it; their sole's centre line
        # (heel and toe sites) is within 2 cm, the punch's pivoting foot rolling onto its edge.
        corners = deepmimic.foot_box_corners(model, qpos)
        assert corners[..., 2].min() == pytest.approx(0.0, abs=1e-9), name
        assert 0.0 <= points[:, SOLE_SITES, 2].min() < 0.02, name
        # Standing height of our pelvis is 0.955 m; crouches and jumps stay plausible.
        assert qpos[:, 2].min() > 0.75 and qpos[:, 2].max() < 1.15, name
        assert 1.2 < points[:, BLAZEPOSE_33.index("nose"), 2].max() < 1.75, name


def test_retarget_respects_joint_limits(retargeted):
    limits = np.radians([JOINT_RANGES_DEG[h] for h in HINGE_NAMES])
    for name, result in retargeted.items():
        angles = result.qpos[:, 7:]
        assert (angles >= limits[:, 0] - 1e-9).all() and (angles <= limits[:, 1] + 1e-9).all()
        assert set(result.clipped) <= set(HINGE_NAMES), name
    assert retargeted["walk"].clipped == {} and retargeted["walk"].rotation_error_deg == {}
    # The punch's right shoulder leaves our range; the twist cap leaves the arm < 50 deg off.
    assert retargeted["punch"].clipped["right_shoulder_y"] > 0.2
    assert max(retargeted["punch"].rotation_error_deg.values()) < 50


def test_retarget_faces_forward_and_moves(retargeted, model):
    walk = retargeted["walk"].qpos
    travel = walk[-1, :2] - walk[0, :2]
    assert np.linalg.norm(travel) > 1.0
    # DeepMimic's walk heads along its +x; ours is the same +x (y up -> z up about x).
    assert travel[0] > 0.95 * np.linalg.norm(travel)
    pelvis_x = body_rotations(walk)[:, 0, :, 0]
    assert (pelvis_x[:, 0] > 0.9).all()
    punch = syn.truth_points(model, retargeted["punch"].qpos)
    speed = np.linalg.norm(np.diff(punch[:, WRISTS], axis=0), axis=-1) * 30
    assert speed.max() > 5.0  # m/s: a punch
    walk_points = syn.truth_points(model, walk)
    assert np.linalg.norm(np.diff(walk_points[:, WRISTS], axis=0), axis=-1).max() * 30 < 4.0


def test_resampling_matches_the_clip(clips):
    full = deepmimic.retarget(clips["kick"])
    half = deepmimic.retarget(clips["kick"], fps=15.0)
    assert len(half) == (len(full) + 1) // 2
    # Same instants, same pose (the floor shift may differ: compare everything but root z).
    assert np.allclose(half[:, 3:], full[::2, 3:], atol=1e-4)
    assert np.allclose(half[:, :2], full[::2, :2], atol=1e-6)


def test_y_up_to_z_up_is_a_rotation():
    c = deepmimic.Y_UP_TO_Z_UP
    assert np.allclose(c @ c.T, np.eye(3)) and np.linalg.det(c) == pytest.approx(1.0)
    assert np.allclose(c @ [0, 1, 0], [0, 0, 1])  # up stays up
    assert np.allclose(c @ [0, 0, 1], [0, -1, 0])  # DeepMimic's right (+z) is our -y


# --------------------------------------------------------------------------
# Cameras
# --------------------------------------------------------------------------


def test_projection_by_hand():
    K = np.array([[1000.0, 0, 960], [0, 1000.0, 540], [0, 0, 1]])
    R, t = look_at(np.array([-5.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0]))
    # Looking along +x: camera right is world -y, camera down is world -z.
    assert np.allclose(R, [[0, -1, 0], [0, 0, -1], [1, 0, 0]])
    points = np.array([[0.0, 0, 1], [0.0, -1, 1], [0.0, 0, 2], [5.0, 1, 1]])
    expected = np.array([[960, 540], [1160, 540], [960, 340], [960 - 100, 540]])
    assert np.allclose(project(points, K, R, t), expected)
    # Round trip: back along the ray to each point's depth.
    depth = (points @ R.T + t)[:, 2]
    uv1 = np.concatenate([expected, np.ones((4, 1))], axis=1)
    back = (depth[:, None] * (uv1 @ np.linalg.inv(K).T) - t) @ R
    assert np.allclose(back, points)


def test_random_camera_looks_at_target():
    rng = np.random.default_rng(3)
    target = np.array([0.5, -0.2, 0.9])
    for _ in range(20):
        K, R, t = syn.random_camera(rng, target)
        centre = -R.T @ t
        assert 4.0 <= np.linalg.norm(centre[:2] - target[:2]) <= 7.0
        assert 1.0 <= centre[2] <= 2.2
        assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)
        assert R[0, 2] == pytest.approx(0.0, abs=1e-12)  # upright: camera x is level
        assert np.allclose(project(target, K, R, t), K[:2, 2])
        fov = 2 * math.degrees(math.atan(960 / K[0, 0]))
        assert 45 <= fov <= 70
    with pytest.raises(ValueError, match="distance"):
        syn.random_camera(rng, target, distance=(7.0, 4.0))


def test_blazepose_like_world(retargeted, model):
    points = syn.truth_points(model, retargeted["walk"].qpos)
    K, R, t = syn.random_camera(np.random.default_rng(0), points[0].mean(axis=0))
    world = syn.blazepose_like_world(points, R)
    assert np.allclose(world[:, list(metrics.HIPS)].mean(axis=1), 0.0, atol=1e-12)
    # A rotation: distances kept; y down: the nose is above (smaller y than) the ankles.
    assert np.allclose(
        np.linalg.norm(world[:, 0] - world[:, 27], axis=-1),
        np.linalg.norm(points[:, 0] - points[:, 27], axis=-1),
    )
    assert (world[:, 0, 1] < world[:, 27, 1]).all()


# --------------------------------------------------------------------------
# Noise and cases
# --------------------------------------------------------------------------


def test_noise_has_the_requested_scale(retargeted, model):
    points = syn.truth_points(model, np.concatenate([r.qpos for r in retargeted.values()]))
    rng = np.random.default_rng(7)
    K, R, t = syn.random_camera(rng, points.reshape(-1, 3).mean(axis=0))
    inputs = syn.noisy_inputs(points, K, R, t, rng)
    residual = inputs.keypoints_2d - project(points, K, R, t)
    assert residual.std() == pytest.approx(5.0, rel=0.05)
    truth = syn.blazepose_like_world(points, R)
    assert metrics.mpjpe_mm(inputs.world_landmarks, truth) == pytest.approx(60.0, rel=0.05)
    assert np.allclose(inputs.world_landmarks[:, list(metrics.HIPS)].mean(axis=1), 0.0)
    assert set(np.unique(inputs.confidence)) <= {0.0, 0.5, 1.0}
    # Correlated noise keeps its size but changes less from frame to frame.
    smooth = syn.noisy_inputs(points, K, R, t, rng, temporal_corr=0.9)
    assert metrics.mpjpe_mm(smooth.world_landmarks, truth) == pytest.approx(60.0, rel=0.15)
    assert metrics.jitter_m_s2(smooth.world_landmarks, 30) < metrics.jitter_m_s2(
        inputs.world_landmarks, 30
    )


def test_make_case_is_seeded(assets: Path):
    a = syn.make_case("punch", 1, assets)
    b = syn.make_case("punch", 1, assets)
    c = syn.make_case("punch", 2, assets)
    assert np.array_equal(a.inputs.keypoints_2d, b.inputs.keypoints_2d)
    assert np.array_equal(a.inputs.world_landmarks, b.inputs.world_landmarks)
    assert not np.allclose(a.R, c.R)
    assert a.fps == 30.0 and a.qpos.shape[1] == 35 and a.points.shape == (len(a.qpos), 33, 3)
    uv = project(a.points, a.K, a.R, a.t)
    assert (uv >= 0).all() and (uv <= np.array(a.size)).all()
    for name in deepmimic.CLIPS:
        case = syn.make_case(name, 0, assets)
        error = metrics.mpjpe_mm(case.inputs.world_landmarks, case.world_landmarks_truth)
        assert 50 < error < 70, name


# --------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------


def _skeleton(rng: np.random.Generator, frames: int = 4) -> np.ndarray:
    return rng.normal(size=(frames, 33, 3)) * 0.3


def test_pa_mpjpe_ignores_similarity_transforms():
    rng = np.random.default_rng(0)
    truth = _skeleton(rng)
    rotation = axis_angle_matrix([0.3, -1.0, 0.5], np.array([0.4, 1.0, 2.5, -2.0]))
    moved = 1.7 * np.einsum("tij,tkj->tki", rotation, truth) + np.array([1.0, -2.0, 0.5])
    assert metrics.pa_mpjpe_mm(moved, truth) == pytest.approx(0.0, abs=1e-6)
    assert metrics.mpjpe_mm(moved, truth) > 100
    assert metrics.mpjpe_mm(moved, truth, align="none") > 100
    assert metrics.mpjpe_mm(truth + 0.05, truth) == pytest.approx(0.0, abs=1e-9)
    assert metrics.mpjpe_mm(truth + [0, 0, 0.05], truth, align="none") == pytest.approx(50.0)
    # A mirror image is not a rotation: Procrustes must not undo it.
    mirrored = truth * np.array([-1.0, 1.0, 1.0])
    assert metrics.pa_mpjpe_mm(mirrored, truth) > 50


def test_metrics_skip_nan_joints():
    rng = np.random.default_rng(1)
    truth = _skeleton(rng)
    pred = truth.copy()
    pred[:, 5, 0] += 0.1  # one joint off by 10 cm ...
    pred[:, 6] = np.nan  # ... one missing
    assert metrics.mpjpe_mm(pred, truth, align="none") == pytest.approx(100 / 32)
    assert np.isfinite(metrics.pa_mpjpe_mm(pred, truth))
    pred[:, list(metrics.HIPS)] = np.nan  # no root: no root-aligned frame left
    with pytest.raises(ValueError, match="no joint is finite"):
        metrics.mpjpe_mm(pred, truth)
    with pytest.raises(ValueError, match="pred and truth"):
        metrics.mpjpe_mm(pred[:2], truth)


def _feet(xy_step: float, z: float, frames: int = 5) -> np.ndarray:
    feet = np.zeros((frames, 2, 3))
    feet[:, :, 0] = np.arange(frames)[:, None] * xy_step
    feet[:, :, 2] = z
    return feet


def test_foot_skating_eq_6_7_by_hand():
    # On the floor: weight 2 - 2^0 = 1, so skating is the slide itself.
    assert metrics.foot_skating_cm_per_frame(_feet(0.02, 0.0)) == pytest.approx(2.0)
    # At or above H nothing counts; half-way, weight 2 - sqrt(2).
    assert metrics.foot_skating_cm_per_frame(_feet(0.02, 0.035)) == 0.0
    assert metrics.foot_skating_cm_per_frame(_feet(0.02, 0.10)) == 0.0
    half = metrics.foot_skating_cm_per_frame(_feet(0.02, 0.0175))
    assert half == pytest.approx(2.0 * (2 - math.sqrt(2)))
    # One foot slides, the other is still: the mean over feet halves it.
    feet = _feet(0.02, 0.0)
    feet[:, 1, 0] = 0.0
    assert metrics.foot_skating_cm_per_frame(feet) == pytest.approx(1.0)
    # Lifting straight up is not skating; sinking below the floor weighs as on it.
    lift = np.zeros((3, 2, 3))
    lift[:, :, 2] = [[0.0, 0.0], [0.01, 0.01], [0.02, 0.02]]
    assert metrics.foot_skating_cm_per_frame(lift) == 0.0
    assert metrics.foot_skating_cm_per_frame(_feet(0.02, -0.01)) == pytest.approx(2.0)
    with pytest.raises(ValueError, match="foot_positions"):
        metrics.foot_skating_cm_per_frame(np.zeros((1, 2, 3)))


def test_plausibility_metrics_by_hand():
    points = np.zeros((3, 2, 3))
    points[:, 0, 2] = [0.01, -0.01, -0.03]
    assert metrics.floor_penetration_mm(points) == pytest.approx((30.0, 40.0 / 3))
    # A bone of length 1, 1, then 1.3 m: std of (1, 1, 1.3) m.
    bones = np.zeros((3, 2, 3))
    bones[:, 1, 0] = [1.0, 1.0, 1.3]
    std = np.std([1.0, 1.0, 1.3]) * 1000
    assert metrics.bone_length_std_mm(bones, [(0, 1)]) == pytest.approx(std)
    # Constant velocity has no acceleration; a 1 cm kick at 30 fps has 2 * 0.01 * 900.
    line = np.zeros((5, 1, 3))
    line[:, 0, 0] = np.arange(5) * 0.1
    assert metrics.jitter_m_s2(line, 30) == pytest.approx(0.0, abs=1e-9)
    line[2, 0, 1] = 0.01
    assert metrics.jitter_m_s2(line, 30) == pytest.approx((9 + 18 + 9) / 3)


def test_truth_is_rigid_and_skates_little(retargeted, model):
    for name, result in retargeted.items():
        points = syn.truth_points(model, result.qpos)
        assert metrics.bone_length_std_mm(points) < 1e-6, name
        assert metrics.foot_skating_cm_per_frame(metrics.sole_points(points)) < 0.1, name
        assert all(0 <= i < 33 and 0 <= j < 33 for i, j in metrics.BLAZEPOSE_BONES)
