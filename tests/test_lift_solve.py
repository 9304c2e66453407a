"""The lift solver on synthetic truth: a scripted boxing motion of the humanoid (stance, steps
with feet planted, punches, sway) seen by a hand-made camera, with 2D and 3D noise added.

The truth is built without the code under test: feet are placed on the floor and the legs
reach them by analytic two-link inverse kinematics, so the true feet neither slide nor sink
while in contact; body rotations become qpos with `qpos_from_body_rotations`.
"""

from __future__ import annotations

import math
import time

import mujoco
import numpy as np
import pytest

from models.humanoid.boxer import BoneLengths, boxer_mjcf, single_scene_mjcf
from models.humanoid.compiled import keypoint_positions
from models.humanoid.fitting import Skeleton
from models.humanoid.fitting import fit_humanoid as fit_with
from models.humanoid.kinematics import (
    BLAZEPOSE_TO_SITE,
    BODY_NAMES,
    JOINT_LAYOUT,
    SITE_NAMES,
    axis_angle_matrix,
    qpos_from_body_rotations,
    quat_to_matrix,
)
from models.humanoid.motion import clean_runs, gaussian_smooth
from models.pose.types import BLAZEPOSE_33
from tasks.config import build
from tasks.lift.camera import project
from tasks.lift.cleanup import (
    Cleaned,
    cleanup,
    cleanup_pair,
    geom_poses,
    lowest_points,
    segment_distances,
)
from tasks.lift.config import LiftConfig
from tasks.lift.lifting import (
    HIPS,
    Lifted3D,
    Lifter,
    OptimisationLifter,
    detect_contacts,
    lift_fighter,
)
from tasks.lift.metrics import (
    bone_length_std_mm,
    foot_skating_cm_per_frame,
    pa_mpjpe_mm,
    sole_points,
)

FPS = 30.0


def fit_humanoid(points, bones):
    """`models.humanoid.fitting.fit_humanoid` with the lift's default IK settings."""
    c = LiftConfig()
    ik = {"iterations": c.ik_iterations, "damping": c.ik_damping, "face_weight": c.ik_face_weight}
    return fit_with(points, bones, **ik)


BONES = BoneLengths().scaled(1.03)
HINGE = {h: 7 + i for i, h in enumerate(h for j in JOINT_LAYOUT for h in j.hinges)}
BODY = {name: i for i, name in enumerate(BODY_NAMES)}


# ---------------------------------------------------------------------------------------------
# Synthetic truth


def _rz(angle: np.ndarray) -> np.ndarray:
    return axis_angle_matrix((0.0, 0.0, 1.0), angle)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _smoothstep(s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, 1.0)
    return s * s * (3 - 2 * s)


def _pulse(frames: int, starts: list[int], rise: int, hold: int, fall: int) -> np.ndarray:
    """0..1 bumps: up over `rise` frames, held, down over `fall` frames."""
    out = np.zeros(frames)
    timeline = np.arange(frames)
    for s in starts:
        up = _smoothstep((timeline - s) / rise)
        down = 1 - _smoothstep((timeline - s - rise - hold) / fall)
        out = np.maximum(out, np.minimum(up, down))
    return out


def _feet(frames: int, rng: np.random.Generator, heading: np.ndarray):
    """Per foot (left, right): ankle positions (T, 3), yaw (T,), pitch, in-contact (T,) bool.

    Orthodox stance about a centre that moves in steps: the lead (left) foot steps first, the
    rear foot follows; steps of 12-30 cm, each swing 8 frames long, lift the ankle by 8 cm.
    The rear foot stands on its toes (heel up by `pitch`), the lead foot flat.
    """
    b = BONES
    pitch = {"left": 0.0, "right": 0.35}
    offsets = {"left": np.array([0.18, 0.12]), "right": np.array([-0.18, -0.12])}
    turn = {"left": 0.15, "right": -0.25}
    centre = np.zeros(2)
    swing = 8

    def place(side: str, frame: int) -> tuple[np.ndarray, float]:
        yaw = heading[frame]
        c, s = math.cos(yaw), math.sin(yaw)
        x, y = offsets[side]
        return centre + np.array([c * x - s * y, s * x + c * y]), yaw + turn[side]

    anchors = {side: [(0, *place(side, 0))] for side in offsets}
    frame = 25
    while frame + 2 * swing + 4 < frames:
        angle, length = rng.uniform(0, 2 * np.pi), rng.uniform(0.12, 0.3)
        step = length * np.array([math.cos(angle), math.sin(angle)])
        centre = centre + (step if np.linalg.norm(centre + step) < 0.5 else -step)
        anchors["left"].append((frame, *place("left", frame + swing)))
        anchors["right"].append((frame + swing + 2, *place("right", frame + 2 * swing + 2)))
        frame += 2 * swing + 2 + int(rng.integers(12, 30))
    out = {}
    for side, plan in anchors.items():
        pos = np.zeros((frames, 3))
        # Toe tip on the floor: the ankle sits above it by toe sin(pitch) + h cos(pitch).
        pos[:, 2] = b.toe_forward * math.sin(pitch[side]) + b.ankle_height * math.cos(pitch[side])
        yaw = np.zeros(frames)
        contact = np.ones(frames, dtype=bool)
        for i, (start, xy, psi) in enumerate(plan):
            land = start if i == 0 else start + swing
            stop = plan[i + 1][0] if i + 1 < len(plan) else frames
            pos[land:stop, :2] = xy
            yaw[land:stop] = psi
            if i + 1 < len(plan):
                _, next_xy, next_psi = plan[i + 1]
                s = _smoothstep((np.arange(swing) + 1) / (swing + 1))
                span = slice(stop, stop + swing)
                pos[span, :2] = xy + s[:, None] * (next_xy - xy)
                pos[span, 2] += 0.08 * np.sin(np.pi * (np.arange(swing) + 1) / (swing + 1))
                yaw[span] = psi + s * (next_psi - psi)
                contact[span] = False
        out[side] = (pos, yaw, pitch[side], contact)
    return out


def _leg(hip: np.ndarray, ankle: np.ndarray, foot_yaw: np.ndarray):
    """Analytic two-link leg: thigh and shin world rotations reaching `ankle` from `hip`, the
    knee in the vertical plane of the foot's forward direction."""
    b = BONES
    l1, l2 = b.thigh, b.shin
    d = ankle - hip
    dist = np.minimum(np.linalg.norm(d, axis=-1), 0.995 * (l1 + l2))
    e = _unit(d)
    forward = np.stack([np.cos(foot_yaw), np.sin(foot_yaw), np.zeros_like(foot_yaw)], -1)
    n = _unit(forward - (forward * e).sum(-1, keepdims=True) * e)
    cos_a = np.clip((l1**2 + dist**2 - l2**2) / (2 * l1 * dist), -1, 1)
    knee = hip + l1 * (cos_a[:, None] * e + np.sqrt(1 - cos_a**2)[:, None] * n)
    ankle = knee + l2 * _unit(hip + dist[:, None] * e - knee)
    z_th = _unit(hip - knee)
    shin_dir = ankle - knee
    x_th = -_unit(shin_dir - (shin_dir * z_th).sum(-1, keepdims=True) * z_th)
    y_th = np.cross(z_th, x_th)
    thigh = np.stack([x_th, y_th, z_th], -1)
    z_sh = _unit(knee - ankle)
    x_sh = np.cross(y_th, z_sh)
    shin = np.stack([x_sh, y_th, z_sh], -1)
    return thigh, shin


def boxing_motion(frames: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A scripted boxing motion of the humanoid built with BONES.

    Returns:
        qpos (T, 35) within the joint limits, and the true contacts (T, 2) (left, right).
    """
    b = BONES
    timeline = np.arange(frames) / FPS
    phase = rng.uniform(0, 2 * np.pi, 8)
    heading = 0.3 * np.sin(2 * np.pi * timeline / 9 + phase[0])
    feet = _feet(frames, rng, heading)
    centre = (feet["left"][0] + feet["right"][0]) / 2
    root = np.zeros((frames, 3))
    root[:, :2] = centre[:, :2] + 0.03 * np.stack(
        [np.sin(2 * np.pi * 0.7 * timeline + phase[1]), np.sin(2 * np.pi * 0.5 * timeline)], -1
    )
    root[:, 2] = b.hip_height - 0.06 + 0.015 * np.sin(2 * np.pi * 1.3 * timeline + phase[2])
    pelvis_yaw = heading - 0.3 + 0.08 * np.sin(2 * np.pi * 0.8 * timeline + phase[3])
    pelvis = _rz(pelvis_yaw)
    rotations = np.broadcast_to(np.eye(3), (frames, len(BODY_NAMES), 3, 3)).copy()
    rotations[:, BODY["pelvis"]] = pelvis
    # Legs: the pelvis origin is mid-hip; hips sit at +-hip_width / 2 along its y axis.
    for side, sign in (("left", 1.0), ("right", -1.0)):
        ankle, foot_yaw, pitch, _ = feet[side]
        hip = root + pelvis @ np.array([0.0, sign * b.hip_width / 2, 0.0])
        thigh, shin = _leg(hip, ankle, foot_yaw)
        rotations[:, BODY[f"{side}_thigh"]] = thigh
        rotations[:, BODY[f"{side}_shin"]] = shin
        rotations[:, BODY[f"{side}_foot"]] = _rz(foot_yaw) @ axis_angle_matrix((0, 1, 0), pitch)
    qpos = qpos_from_body_rotations(root, rotations)
    # Upper body: hinge angles directly (children of the pelvis above).
    jabs = _pulse(frames, list(range(10, frames - 20, 37)), 4, 1, 6)
    crosses = _pulse(frames, list(range(28, frames - 20, 53)), 5, 1, 7)
    wave = np.sin(2 * np.pi * 0.6 * timeline + phase[4])
    angles = {
        "abdomen_y": 0.25 + 0.06 * wave,
        "abdomen_x": 0.05 * np.sin(2 * np.pi * 0.4 * timeline + phase[5]),
        "abdomen_z": 0.25 + 0.1 * wave - 0.35 * crosses + 0.15 * jabs,
        "neck_y": -0.2 - 0.05 * wave,
        "neck_x": 0.05 * np.sin(2 * np.pi * 0.3 * timeline),
        "neck_z": -0.2 + 0.25 * crosses,
        "left_shoulder_y": -0.35 - 1.1 * jabs,
        "left_shoulder_x": -0.25 + 0.2 * jabs,
        "left_shoulder_z": 0.3 * np.sin(2 * np.pi * 0.5 * timeline + phase[6]),
        "left_elbow": 2.1 - 1.9 * jabs,
        "right_shoulder_y": -0.3 - 1.15 * crosses,
        "right_shoulder_x": 0.3 - 0.25 * crosses,
        "right_shoulder_z": -0.2 + 0.2 * np.sin(2 * np.pi * 0.4 * timeline + phase[7]),
        "right_elbow": 2.2 - 2.0 * crosses,
    }
    for name, value in angles.items():
        qpos[:, HINGE[name]] = value
    contacts = np.stack([feet["left"][3], feet["right"][3]], axis=1)
    return qpos, contacts


def _camera() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """K, R, t of a 1080p camera 5.5 m from the ring centre, 1.7 m up, looking at the fighter."""
    K = np.array([[1400.0, 0.0, 960.0], [0.0, 1400.0, 540.0], [0.0, 0.0, 1.0]])
    centre = np.array([1.0, -5.4, 1.7])
    forward = _unit(np.array([0.0, 0.0, 1.0]) - centre)
    right = _unit(np.cross(forward, [0.0, 0.0, 1.0]))
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    return K, R, -R @ centre


def _observe(points: np.ndarray, rng: np.random.Generator, *, px: float = 5.0):
    """2D keypoints (5 px noise, a few outliers), confidences, and world landmarks (camera
    axes, about the hip centre) with 60 mm mean error: white noise plus a slowly drifting bias
    per joint (BlazePose's errors are partly systematic)."""
    K, R, t = _camera()
    frames = len(points)
    keypoints = project(points, K, R, t) + rng.normal(0.0, px, (frames, 33, 2))
    confidence = rng.uniform(0.6, 1.0, (frames, 33))
    outliers = rng.random((frames, 33)) < 0.01
    keypoints[outliers] += rng.normal(0.0, 60.0, (outliers.sum(), 2))
    confidence[outliers] = 0.3
    hip = points[:, list(HIPS)].mean(1, keepdims=True)
    drift = gaussian_smooth(rng.normal(0.0, 1.0, (frames, 33, 3)), 6.0)
    drift *= 0.022 / drift.std()
    landmarks = (points - hip) @ R.T + rng.normal(0.0, 0.031, (frames, 33, 3)) + drift
    return keypoints, confidence, landmarks


@pytest.fixture(scope="module")
def scene() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(single_scene_mjcf(BONES))


@pytest.fixture(scope="module")
def truth(scene: mujoco.MjModel) -> dict[str, np.ndarray]:
    qpos, contacts = boxing_motion(150, np.random.default_rng(7))
    return {"qpos": qpos, "contacts": contacts, "points": keypoint_positions(scene, qpos)}


@pytest.fixture(scope="module")
def lifted(truth: dict[str, np.ndarray]) -> tuple[Lifted3D, np.ndarray]:
    observed = _observe(truth["points"], np.random.default_rng(11))
    K, R, t = _camera()
    return lift_fighter(*observed, K, R, t, fps=FPS), observed[2]


def _within_ranges(model: mujoco.MjModel, qpos: np.ndarray) -> bool:
    lo, hi = model.jnt_range[1:29].T
    return bool(((qpos[:, 7:] >= lo - 1e-9) & (qpos[:, 7:] <= hi + 1e-9)).all())


def test_truth_is_a_physical_motion(scene: mujoco.MjModel, truth: dict[str, np.ndarray]) -> None:
    """The generator's own check: joint limits kept, contact feet on the floor and still."""
    assert _within_ranges(scene, truth["qpos"])
    lowest = lowest_points(geom_poses(scene, truth["qpos"]))
    assert lowest.min() > -1e-9
    feet = geom_poses(scene, truth["qpos"])
    foot_low = lowest_points(feet)[:, list(feet.foot)]
    assert np.abs(foot_low[truth["contacts"]]).max() < 1e-9
    assert foot_skating_cm_per_frame(sole_points(truth["points"])) < 0.05
    assert 0.6 < truth["contacts"].mean() < 0.95  # it steps


# ---------------------------------------------------------------------------------------------
# Building blocks against slow, obvious references


def test_skeleton_matches_mujoco_and_its_jacobian_finite_differences(
    scene: mujoco.MjModel, truth: dict[str, np.ndarray]
) -> None:
    skeleton = Skeleton.from_model(scene)
    qpos = truth["qpos"][::15]
    pose = (qpos[:, :3], quat_to_matrix(qpos[:, 3:7]), qpos[:, 7:])
    body_pos, _, axes, sites = skeleton.forward(*pose)
    site_of = [SITE_NAMES.index(BLAZEPOSE_TO_SITE[n]) for n in BLAZEPOSE_33]
    np.testing.assert_allclose(sites[:, site_of], keypoint_positions(scene, qpos), atol=1e-12)
    index = np.arange(len(SITE_NAMES))
    jac = skeleton.jacobian(pose[0], body_pos, axes, sites, index)
    step = 1e-6
    for dof in (0, 4, 6 + 9, 6 + 17, 6 + 27):  # translation, rotation, hinges
        delta = np.zeros(34)
        delta[dof] = step
        rotvec = np.broadcast_to(delta[3:6], (len(qpos), 3))
        angle = np.linalg.norm(rotvec[0])
        turn = axis_angle_matrix(rotvec[0] / angle, angle) if angle else np.eye(3)
        moved = skeleton.forward(pose[0] + delta[:3], turn @ pose[1], pose[2] + delta[6:])[3]
        np.testing.assert_allclose((moved - sites) / step, jac[..., dof], atol=1e-5)


def test_segment_distances_match_dense_sampling() -> None:
    rng = np.random.default_rng(0)
    p1, q1, p2, q2 = (rng.normal(size=(400, 3)) for _ in range(4))
    q1[:50] = p1[:50]  # points as well as segments, on either side
    q2[25:75] = p2[25:75]
    distance, c1, c2 = segment_distances(p1, q1, p2, q2)
    s = np.linspace(0.0, 1.0, 301)[None, :, None]
    a = p1[:, None] + s * (q1 - p1)[:, None]
    b = p2[:, None] + s * (q2 - p2)[:, None]
    dense = np.linalg.norm(a[:, :, None] - b[:, None], axis=-1).min(axis=(1, 2))
    assert np.all(distance <= dense + 1e-12) and np.all(distance > dense - 0.01)
    np.testing.assert_allclose(np.linalg.norm(c1 - c2, axis=-1), distance, atol=1e-12)


def test_clean_runs_and_smoothing() -> None:
    mask = np.array([1, 1, 1, 0, 1, 1, 1, 1, 0, 0, 0, 0, 1, 0, 0], dtype=bool)
    expected = np.array([1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0], dtype=bool)
    np.testing.assert_array_equal(clean_runs(mask, 3), expected)
    line = np.linspace(0.0, 3.0, 20)[:, None] * np.array([1.0, -2.0])
    np.testing.assert_allclose(gaussian_smooth(line, 2.0), line, atol=1e-12)  # keeps trends


# ---------------------------------------------------------------------------------------------
# Lift


def test_lift_fuses_noisy_inputs_into_accurate_rigid_3d(
    truth: dict[str, np.ndarray], lifted: tuple[Lifted3D, np.ndarray]
) -> None:
    result, landmarks = lifted
    before = pa_mpjpe_mm(landmarks, truth["points"])
    after = pa_mpjpe_mm(result.points, truth["points"])
    stretch = bone_length_std_mm(result.points)
    print(
        f"\nlift: PA-MPJPE {before:.1f} mm (noisy landmarks) -> {after:.1f} mm; bone std "
        f"{bone_length_std_mm(landmarks):.1f} -> {stretch:.2f} mm"
    )
    assert before > 45.0  # the noise is what the task says
    assert after < 40.0 and after <= 0.7 * before
    assert stretch < 5.0
    assert result.points.shape == truth["points"].shape
    assert result.bones.shin == pytest.approx(BONES.shin, abs=0.02)


def test_lift_detects_foot_contacts(
    truth: dict[str, np.ndarray], lifted: tuple[Lifted3D, np.ndarray]
) -> None:
    contacts = lifted[0].contacts
    assert contacts.shape == truth["contacts"].shape and contacts.dtype == bool
    agree = (contacts == truth["contacts"]).mean()
    print(f"\ncontacts: {agree:.0%} of foot-frames agree with the truth")
    assert agree > 0.8


def test_lift_from_root_init_and_through_missing_frames(truth: dict[str, np.ndarray]) -> None:
    K, R, t = _camera()
    keypoints, confidence, landmarks = _observe(truth["points"], np.random.default_rng(5))
    keypoints[40:48] = np.nan  # the fighter was not detected
    confidence[40:48] = 0.0
    landmarks[40:48] = np.nan
    hip = truth["points"][:, list(HIPS)].mean(1)
    root = hip + np.random.default_rng(6).normal(0.0, 0.02, hip.shape)
    root[42:46] = np.nan  # not placed either: interpolated
    result = lift_fighter(keypoints, confidence, landmarks, K, R, t, fps=FPS, root_init=root)
    assert np.isfinite(result.points).all()
    placed = np.linalg.norm(result.points - truth["points"], axis=-1).mean()
    assert placed < 0.06  # metres, absolute: the fighter is where it stands
    assert pa_mpjpe_mm(result.points, truth["points"]) < 35.0


def test_optimisation_lifter_is_a_lifter(truth: dict[str, np.ndarray]) -> None:
    K, R, t = _camera()
    observed = _observe(truth["points"][:20], np.random.default_rng(1))
    lifter = OptimisationLifter(LiftConfig(iterations=5, contact_iterations=2))
    assert isinstance(lifter, Lifter)
    result = lifter(*observed, K, R, t, fps=FPS)
    direct = lift_fighter(*observed, K, R, t, fps=FPS, config=lifter.config)
    np.testing.assert_allclose(result.points, direct.points)


# ---------------------------------------------------------------------------------------------
# Humanoid fit


def test_fit_recovers_the_truth(scene: mujoco.MjModel, truth: dict[str, np.ndarray]) -> None:
    qpos = fit_humanoid(truth["points"], BONES)
    assert qpos.shape == (len(truth["points"]), 35)
    assert _within_ranges(scene, qpos)
    error = np.linalg.norm(keypoint_positions(scene, qpos) - truth["points"], axis=-1)
    assert error.max() < 1e-3
    np.testing.assert_allclose(qpos[:, 7:], truth["qpos"][:, 7:], atol=1e-3)


def test_fit_keeps_joint_limits(scene: mujoco.MjModel, truth: dict[str, np.ndarray]) -> None:
    """Joints bent past their limits (elbow and knee backwards) give a fit within the limits
    that beats the truth clipped to them."""
    bent = truth["qpos"][:30].copy()
    bent[:, HINGE["right_elbow"]] = -0.4
    bent[:, HINGE["left_knee"]] = -0.3
    points = keypoint_positions(scene, bent)  # kinematics alone: no limits
    qpos = fit_humanoid(points, BONES)
    assert _within_ranges(scene, qpos)
    assert np.abs(qpos[:, HINGE["left_knee"]]).max() < 0.02  # on its limit
    clipped = bent.copy()
    clipped[:, 7:] = np.clip(bent[:, 7:], *scene.jnt_range[1:29].T)
    error = np.linalg.norm(keypoint_positions(scene, qpos) - points, axis=-1).mean()
    reference = np.linalg.norm(keypoint_positions(scene, clipped) - points, axis=-1).mean()
    assert error < 0.5 * reference


def test_fit_of_lifted_points_is_close_to_them(lifted: tuple[Lifted3D, np.ndarray]) -> None:
    result = lifted[0]
    qpos = fit_humanoid(result.points, result.bones)
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(result.bones))
    assert _within_ranges(model, qpos)
    error = np.linalg.norm(keypoint_positions(model, qpos) - result.points, axis=-1).mean()
    assert error < 0.03


# ---------------------------------------------------------------------------------------------
# Cleanup


def test_cleanup_puts_feet_on_the_floor_without_skating(
    scene: mujoco.MjModel, truth: dict[str, np.ndarray]
) -> None:
    """Sunk by 0.5-2.5 cm, swaying 2 cm (skating) and jittering: cleanup restores the truth."""
    rng = np.random.default_rng(3)
    qpos = truth["qpos"].copy()
    time_s = np.arange(len(qpos)) / FPS
    qpos[:, 2] += -0.015 + 0.01 * np.sin(2 * np.pi * 0.5 * time_s)
    qpos[:, 0] += 0.02 * np.sin(2 * np.pi * time_s)
    qpos[:, 1] += 0.015 * np.sin(2 * np.pi * 0.7 * time_s + 1.0)
    lo, hi = scene.jnt_range[1:29].T
    qpos[:, 7:] = np.clip(qpos[:, 7:] + rng.normal(0.0, 0.005, (len(qpos), 28)), lo, hi)
    points = keypoint_positions(scene, qpos)
    contacts = detect_contacts(points, fps=FPS)  # detected, not taken from the truth
    assert (contacts == truth["contacts"]).mean() > 0.85

    result = cleanup(scene, qpos, contacts, fps=FPS)
    assert isinstance(result, Cleaned) and result.qvel.shape == (len(qpos), 34)
    assert _within_ranges(scene, result.qpos)
    sunk = -lowest_points(geom_poses(scene, result.qpos)).min()
    skate_before = foot_skating_cm_per_frame(sole_points(points))
    skate_after = foot_skating_cm_per_frame(sole_points(result.points))
    print(
        f"\ncleanup: floor penetration {result.metrics['floor_penetration_mm_before']:.1f} -> "
        f"{result.metrics['floor_penetration_mm_after']:.1f} mm; skating (FSE) "
        f"{skate_before:.3f} -> {skate_after:.3f} cm/frame"
    )
    assert sunk < 0.01 and result.metrics["floor_penetration_mm_after"] < 10.0
    assert skate_after < 0.5 * skate_before
    assert result.metrics["contact_slide_cm_per_frame_after"] < 0.1
    error = np.linalg.norm(result.points - truth["points"], axis=-1).mean()
    assert error < np.linalg.norm(points - truth["points"], axis=-1).mean()
    np.testing.assert_allclose(result.points, keypoint_positions(scene, result.qpos))


def test_a_floating_fighter_is_settled_on_the_floor_and_a_hop_is_kept(
    scene: mujoco.MjModel, truth: dict[str, np.ndarray]
) -> None:
    """Lifted 30 cm into the air (the sample's adversary was 31 cm up) with a 0.2 s hop of a
    further 10 cm: the cleanup puts him back on the floor and leaves the hop in the air."""
    qpos = truth["qpos"].copy()
    hop = slice(60, 66)  # 6 frames at 30 fps
    qpos[:, 2] += 0.3
    qpos[hop, 2] += 0.1
    contacts = np.zeros_like(truth["contacts"])  # as for the sample's: the lift saw none
    result = cleanup(scene, qpos, contacts, fps=FPS)
    lowest = lowest_points(geom_poses(scene, result.qpos)).min(1)
    assert result.metrics["foot_height_cm_before"] > 29
    assert result.metrics["foot_height_cm_after"] < 2
    assert result.metrics["floor_settle_cm"] == pytest.approx(30, abs=2)
    assert np.median(lowest) < 0.02 and lowest.min() > -0.01
    assert lowest[hop].min() > 0.03 and lowest[hop].max() > 0.07  # still in the air
    np.testing.assert_allclose(result.settle, 0.3, atol=0.03)
    off = cleanup(scene, qpos, contacts, fps=FPS, config=LiftConfig(floor_settle_s=0))
    assert off.metrics["foot_height_cm_after"] > 25 and not off.settle.any()


def _turned(qpos: np.ndarray, yaw: float, offset: np.ndarray) -> np.ndarray:
    """A motion turned by `yaw` about z, then moved by `offset`."""
    out = qpos.copy()
    out[:, :3] = qpos[:, :3] @ axis_angle_matrix((0.0, 0.0, 1.0), yaw).T + offset
    turn = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    for frame in range(len(out)):
        mujoco.mju_mulQuat(out[frame, 3:7], turn, qpos[frame, 3:7])
    return out


def _pair_penetration(bones: tuple[BoneLengths, BoneLengths], qpos_a, qpos_b) -> np.ndarray:
    """Per frame, the deepest contact MuJoCo finds between the two fighters (metres)."""
    spec = mujoco.MjSpec.from_string(single_scene_mjcf(bones[0]))
    blue = mujoco.MjSpec.from_string(boxer_mjcf(bones[1], contype=2, conaffinity=1))
    spec.worldbody.add_frame().attach_body(blue.body("pelvis"), "blue/", "")
    model = spec.compile()
    data = mujoco.MjData(model)
    blue_bodies = {model.body(f"blue/{name}").id for name in BODY_NAMES}
    depth = np.zeros(len(qpos_a))
    for frame in range(len(qpos_a)):
        data.qpos[:] = np.concatenate([qpos_a[frame], qpos_b[frame]])
        mujoco.mj_fwdPosition(model, data)
        for contact in data.contact[: data.ncon]:
            sides = {model.geom_bodyid[g] in blue_bodies for g in (contact.geom1, contact.geom2)}
            floor = model.geom("floor").id in (contact.geom1, contact.geom2)
            if sides == {True, False} and not floor:
                depth[frame] = max(depth[frame], -contact.dist)
    return depth


def test_cleanup_pushes_overlapping_fighters_apart() -> None:
    bones = (BONES, BoneLengths().scaled(0.97))
    models = tuple(mujoco.MjModel.from_xml_string(single_scene_mjcf(b)) for b in bones)
    red, red_contacts = boxing_motion(90, np.random.default_rng(1))
    blue, blue_contacts = boxing_motion(90, np.random.default_rng(2))
    blue = _turned(blue, math.pi, np.array([0.5, 0.0, 0.0]))  # facing red, far too close
    before = _pair_penetration(bones, red, blue)
    first, second = cleanup_pair(models, (red, blue), (red_contacts, blue_contacts), fps=FPS)
    after = _pair_penetration(bones, first.qpos, second.qpos)
    gap = np.linalg.norm(first.qpos[:, :2] - second.qpos[:, :2], axis=1)
    print(
        f"\nseparation: inter-fighter penetration {before.max() * 1000:.0f} -> "
        f"{after.max() * 1000:.1f} mm (MuJoCo contacts); roots {gap.min():.2f}-{gap.max():.2f} m "
        "apart"
    )
    assert before.max() > 0.05
    assert after.max() < 0.01
    assert second.metrics["interpenetration_mm_after"] < 10.0
    assert gap.max() < 2.0  # apart, not flung away
    for result in (first, second):
        assert result.metrics["floor_penetration_mm_after"] < 10.0
        assert result.metrics["contact_slide_cm_per_frame_after"] < 0.2


def test_a_fighter_entering_late_is_cleaned_over_its_own_frames() -> None:
    """Blue enters 40 frames after red. Cleaned together, blue stays where its lift put it from
    its first frame: before, both were filtered over the shot with blue parked 1 km away while
    absent, and blue's first frames came out up to 214 m off (a person stepping out from
    behind an occluder in a video)."""
    bones = (BONES, BoneLengths().scaled(0.97))
    models = tuple(mujoco.MjModel.from_xml_string(single_scene_mjcf(b)) for b in bones)
    red, red_contacts = boxing_motion(90, np.random.default_rng(1))
    blue, blue_contacts = boxing_motion(50, np.random.default_rng(2))
    blue = _turned(blue, math.pi, np.array([1.5, 0.0, 0.0]))
    first, second = cleanup_pair(
        models, (red, blue), (red_contacts, blue_contacts), fps=FPS, spans=((0, 90), (40, 90))
    )
    assert first.qpos.shape == red.shape and second.qpos.shape == blue.shape
    moved = np.linalg.norm(second.qpos[:, :3] - blue[:, :3], axis=1)
    assert moved.max() < 0.1, moved.max()
    assert np.linalg.norm(first.qpos[:, :3] - red[:, :3], axis=1).max() < 0.1


def test_qvel_is_the_central_difference_of_qpos(
    scene: mujoco.MjModel, truth: dict[str, np.ndarray]
) -> None:
    qpos = truth["qpos"][:20]
    result = cleanup(scene, qpos, truth["contacts"][:20], fps=FPS)
    for frame in range(1, 19):
        ahead = result.qpos[frame - 1].copy()
        mujoco.mj_integratePos(scene, ahead, result.qvel[frame], 2.0 / FPS)
        np.testing.assert_allclose(ahead, result.qpos[frame + 1], atol=1e-9)


# ---------------------------------------------------------------------------------------------
# Interface


def test_config_builds_from_text_and_rejects_bad_values() -> None:
    config = build(LiftConfig, {"iterations": "12", "shape_sigma_m": "0.05"}, section="lift")
    assert config.iterations == 12 and config.shape_sigma_m == 0.05
    with pytest.raises(ValueError, match="shape_sigma_m"):
        LiftConfig(shape_sigma_m=0.0)
    with pytest.raises(ValueError, match="separation_share"):
        LiftConfig(separation_share=1.5)


def test_bad_arguments_are_named(scene: mujoco.MjModel, truth: dict[str, np.ndarray]) -> None:
    K, R, t = _camera()
    keypoints, confidence, landmarks = _observe(truth["points"][:10], np.random.default_rng(0))
    with pytest.raises(ValueError, match="keypoints_2d"):
        lift_fighter(keypoints[..., :1], confidence, landmarks, K, R, t, fps=FPS)
    with pytest.raises(ValueError, match="world_landmarks"):
        lift_fighter(keypoints, confidence, landmarks[:5], K, R, t, fps=FPS)
    with pytest.raises(ValueError, match="fps"):
        lift_fighter(keypoints, confidence, landmarks, K, R, t, fps=0.0)
    with pytest.raises(ValueError, match="root_init"):
        lift_fighter(keypoints, confidence, landmarks, K, R, t, fps=FPS, root_init=np.zeros(3))
    with pytest.raises(ValueError, match="root_init"):
        lift_fighter(
            keypoints, confidence, landmarks, K, R, t, fps=FPS, root_init=np.full((10, 3), np.inf)
        )
    with pytest.raises(ValueError, match="R must be a rotation"):
        lift_fighter(keypoints, confidence, landmarks, K, 2 * R, t, fps=FPS)
    with pytest.raises(ValueError, match="points"):
        fit_humanoid(np.zeros((4, 17, 3)), BONES)
    with pytest.raises(ValueError, match="contacts"):
        cleanup(scene, truth["qpos"][:10], np.zeros((10, 3), bool), fps=FPS)
    with pytest.raises(ValueError, match="other_qpos"):
        cleanup(scene, truth["qpos"][:10], truth["contacts"][:10], fps=FPS,
                other_qpos=truth["qpos"][:9])  # fmt: skip
    pair = mujoco.MjModel.from_xml_string(boxer_mjcf(BONES, prefix="red/"))
    with pytest.raises(ValueError, match="model"):
        cleanup(pair, truth["qpos"][:10], truth["contacts"][:10], fps=FPS)


# ---------------------------------------------------------------------------------------------
# Speed (reported, not asserted)


def test_speed_report(scene: mujoco.MjModel) -> None:
    """Frames per second of each step on 300 frames (10 s at 30 fps) of one fighter."""
    qpos, _ = boxing_motion(300, np.random.default_rng(3))
    points = keypoint_positions(scene, qpos)
    observed = _observe(points, np.random.default_rng(4))
    K, R, t = _camera()
    start = time.perf_counter()
    result = lift_fighter(*observed, K, R, t, fps=FPS)
    lifted_at = time.perf_counter()
    fitted = fit_humanoid(result.points, result.bones)
    fitted_at = time.perf_counter()
    model = mujoco.MjModel.from_xml_string(single_scene_mjcf(result.bones))
    cleaned = cleanup(model, fitted, result.contacts, fps=FPS)
    done = time.perf_counter()
    frames = len(points)
    print(
        f"\nspeed, {frames} frames: lift {frames / (lifted_at - start):.0f} fps, fit "
        f"{frames / (fitted_at - lifted_at):.0f} fps, cleanup {frames / (done - fitted_at):.0f} "
        f"fps; all {frames / (done - start):.0f} fps. PA-MPJPE "
        f"{pa_mpjpe_mm(observed[2], points):.1f} (input) -> "
        f"{pa_mpjpe_mm(result.points, points):.1f} (lift) -> "
        f"{pa_mpjpe_mm(cleaned.points, points):.1f} mm (cleaned)"
    )
    assert np.isfinite(cleaned.qvel).all()
