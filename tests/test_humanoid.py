"""The boxer humanoid: its MJCF, bone scaling, and the kinematics conversions."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from models.humanoid import compiled
from models.humanoid import kinematics as K
from models.humanoid.boxer import (
    DEFAULT_GAINS,
    JOINT_RANGES_DEG,
    KNEE_LOCK_RAD,
    TIMESTEP,
    BoneLengths,
    boxer_mjcf,
    gain_scale,
    single_scene_mjcf,
)
from models.pose.types import BLAZEPOSE_33, COCO_17

# A short, wide-shouldered fighter: every field differs from a uniform scaling.
SMALL = BoneLengths(
    pelvis_to_torso=0.10,
    torso_to_neck=0.33,
    neck_to_head=0.21,
    head_radius=0.10,
    shoulder_width=0.39,
    upper_arm=0.29,
    forearm=0.24,
    hand=0.08,
    hip_width=0.18,
    thigh=0.40,
    shin=0.41,
    ankle_height=0.065,
    foot=0.20,
    heel=0.09,
)
SIZES = [BoneLengths(), SMALL, BoneLengths().scaled(1.08)]


def _model(bones: BoneLengths = BoneLengths(), scene: bool = False) -> mujoco.MjModel:  # noqa: B008
    xml = single_scene_mjcf(bones) if scene else boxer_mjcf(bones)
    return mujoco.MjModel.from_xml_string(xml)


def _random_qpos(rng: np.random.Generator, n: int, margin_deg: float = 2.0) -> np.ndarray:
    """(n, 35) qpos: random root pose, hinge angles uniform inside the joint limits."""
    lo, hi = np.radians(np.array(list(JOINT_RANGES_DEG.values())).T)
    margin = math.radians(margin_deg)
    qpos = np.zeros((n, K.NQ))
    qpos[:, :3] = rng.normal(0.0, 1.0, (n, 3))
    quat = rng.normal(size=(n, 4))
    qpos[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    qpos[:, 7:] = rng.uniform(lo + margin, hi - margin, (n, K.NUM_ACTUATED))
    return qpos


def _yaw_quat(yaw: float) -> np.ndarray:
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty(4)
    mujoco.mju_mulQuat(out, a, b)
    return out


# --------------------------------------------------------------------------
# The MJCF
# --------------------------------------------------------------------------


def test_mjcf_compiles_with_the_papers_layout() -> None:
    model = _model()
    assert model.nbody == 1 + 15
    assert [model.body(i).name for i in range(1, 16)] == list(K.BODY_NAMES)
    assert (model.nq, model.nv, model.nu) == (7 + 28, 6 + 28, 28)
    assert [model.actuator(i).name for i in range(model.nu)] == list(K.HINGE_NAMES)
    assert model.opt.timestep == pytest.approx(1 / 120)
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    # Parents as PARENTS says; hands welded (no joint), everything else jointed.
    assert [int(model.body_parentid[i]) - 1 for i in range(1, 16)] == list(K.PARENTS)
    hands = {K.BODY_NAMES.index("left_hand") + 1, K.BODY_NAMES.index("right_hand") + 1}
    for body in range(1, 16):
        assert (model.body_jntnum[body] == 0) == (body in hands)
    index = compiled.humanoid_index(model)
    assert (index.qpos_start, index.qvel_start) == (0, 0)


@pytest.mark.parametrize("bones", [BoneLengths(), SMALL])
def test_joint_limits_gains_and_axes(bones: BoneLengths) -> None:
    model = _model(bones)
    scale = gain_scale(24.0 * bones.stature**2, bones.stature)
    assert scale == pytest.approx(
        1.0 if bones == BoneLengths() else (bones.stature / 1.78) ** 3, rel=0.02
    )
    group = {hinge: spec.group for spec in K.JOINT_LAYOUT for hinge in spec.hinges}
    for hinge, (lo, hi) in JOINT_RANGES_DEG.items():
        joint = model.joint(hinge)
        assert joint.type[0] == mujoco.mjtJoint.mjJNT_HINGE
        assert joint.limited[0]
        np.testing.assert_allclose(joint.range, np.radians([lo, hi]))
        actuator = model.actuator(hinge)
        gains = DEFAULT_GAINS[group[hinge]]
        kp = actuator.gainprm[0]
        assert kp == pytest.approx(gains.kp * scale)
        assert 299 * scale <= kp <= 2501 * scale
        assert model.dof_damping[joint.dofadr[0]] == pytest.approx(gains.kd * scale)
        assert actuator.biasprm[1] == pytest.approx(-kp)  # position servo: -kp q
        assert actuator.forcerange[1] == pytest.approx(gains.max_torque * scale)
        # A knee's target may press past straight into its limit (a locked knee); the rest
        # stay within the joint's range.
        lock = KNEE_LOCK_RAD if group[hinge] == "knee" else 0.0
        np.testing.assert_allclose(actuator.ctrlrange, joint.range - [lock, 0.0])
        assert actuator.forcelimited[0]
    for spec in K.JOINT_LAYOUT:
        for hinge, axis in zip(spec.hinges, spec.axes, strict=True):
            np.testing.assert_allclose(model.joint(hinge).axis, axis)


def test_masses_follow_body_mass_and_gloves() -> None:
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(body_mass=70.0, glove_mass=0.28))
    assert model.body_subtreemass[1] == pytest.approx(70.0 + 2 * 0.28)
    hand = model.body("right_hand").mass[0]
    assert hand == pytest.approx(0.006 * 70.0 + 0.28)
    assert model.geom("right_glove").type[0] == mujoco.mjtGeom.mjGEOM_SPHERE
    assert model.geom("head").type[0] == mujoco.mjtGeom.mjGEOM_SPHERE
    assert model.geom("left_foot").type[0] == mujoco.mjtGeom.mjGEOM_BOX
    assert np.all(model.body_inertia[1:] > 0)


@pytest.mark.parametrize("bones", SIZES)
def test_stands_with_soles_on_the_floor_at_qpos0(bones: BoneLengths) -> None:
    model = _model(bones, scene=True)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert data.qpos[2] == pytest.approx(bones.hip_height)
    sites = compiled.site_positions(model, data)
    for side in ("left", "right"):
        assert sites[f"{side}_heel"][2] == pytest.approx(0.0, abs=1e-9)
        assert sites[f"{side}_foot_index"][2] == pytest.approx(0.0, abs=1e-9)
        foot = model.geom(f"{side}_foot").id
        corners = (
            data.geom_xpos[foot]
            + np.array([[sx, sy, -1.0] for sx in (-1, 1) for sy in (-1, 1)])
            * model.geom_size[foot]
            @ data.geom_xmat[foot].reshape(3, 3).T
        )
        np.testing.assert_allclose(corners[:, 2], 0.0, atol=1e-9)
    # Nothing else reaches below the soles.
    lowest = min(
        data.geom_xpos[g][2] - model.geom_rbound[g]
        for g in range(model.ngeom)
        if model.geom_bodyid[g] not in (0,) and model.geom_type[g] != mujoco.mjtGeom.mjGEOM_BOX
    )
    assert lowest > 0.0
    assert bones.stature - 0.25 < sites["nose"][2] < bones.stature


def test_holds_its_standing_pose_under_pd_control() -> None:
    """Actuators targeting qpos0 keep it upright: 3 s of physics, not just 0.5 s."""
    model = _model(scene=True)
    data = mujoco.MjData(model)
    data.ctrl[:] = 0.0
    steps = round(3.0 / TIMESTEP)
    for _ in range(steps):
        mujoco.mj_step(model, data)
    assert np.all(np.isfinite(data.qpos))
    assert data.qpos[2] > 0.97 * BoneLengths().hip_height
    up = data.xmat[compiled.humanoid_index(model).body_ids[1]].reshape(3, 3)[:, 2]
    assert up[2] > math.cos(math.radians(5.0))
    assert np.abs(data.qpos[7:]).max() < math.radians(5.0)


def test_random_targets_stay_finite() -> None:
    """Random joint targets at 30 Hz (4 substeps): falls, but never diverges."""
    model = _model(scene=True)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(3)
    lo, hi = model.actuator_ctrlrange.T
    for step in range(240):
        if step % 4 == 0:
            data.ctrl[:] = rng.uniform(lo, hi)
        mujoco.mj_step(model, data)
    assert np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))


def test_two_fighters_combine_with_prefixes() -> None:
    arena = mujoco.MjSpec.from_string(single_scene_mjcf(BoneLengths()))
    blue = mujoco.MjSpec.from_string(boxer_mjcf(SMALL, contype=2, conaffinity=1))
    frame = arena.worldbody.add_frame(pos=[1.2, 0.0, 0.0], quat=[0.0, 0.0, 0.0, 1.0])
    frame.attach_body(blue.body("pelvis"), "blue/", "")
    model = arena.compile()
    assert (model.nq, model.nu) == (2 * 35, 2 * 28)
    red, other = compiled.humanoid_index(model), compiled.humanoid_index(model, prefix="blue/")
    assert (red.qpos, other.qpos) == (slice(0, 35), slice(35, 70))
    data = mujoco.MjData(model)
    pos, _ = compiled.forward_kinematics(model, data.qpos, prefix="blue/", data=data)
    assert pos[0] == pytest.approx([1.2, 0.0, SMALL.hip_height])
    # Gloves hit the other fighter; a fighter's own geoms never touch each other.
    red_glove, blue_head = model.geom("right_glove"), model.geom("blue/head")
    assert red_glove.contype[0] & blue_head.conaffinity[0]
    assert not (red_glove.contype[0] & model.geom("head").conaffinity[0])


def test_bad_arguments_are_named() -> None:
    with pytest.raises(ValueError, match="upper_arm"):
        BoneLengths(upper_arm=-0.3)
    with pytest.raises(ValueError, match="heel"):
        BoneLengths(heel=0.05, ankle_height=0.07)
    with pytest.raises(ValueError, match="rgba"):
        boxer_mjcf(rgba=(1.0, 0.0))
    with pytest.raises(ValueError, match="body_mass"):
        boxer_mjcf(body_mass=-1.0)
    with pytest.raises(ValueError, match="points"):
        BoneLengths.from_points(np.zeros((4, 17, 3)))
    with pytest.raises(ValueError, match="rotation"):
        K.tangent_normal(np.eye(4))
    with pytest.raises(ValueError, match="qpos"):
        compiled.forward_kinematics(_model(), np.zeros(10))
    with pytest.raises(ValueError, match="red/pelvis"):
        compiled.humanoid_index(_model(), prefix="red/")


# --------------------------------------------------------------------------
# Bones
# --------------------------------------------------------------------------


def _measured(points: np.ndarray) -> dict[str, float]:
    """Segment lengths of one BlazePose-order skeleton (33, 3)."""

    def at(name: str) -> np.ndarray:
        return points[BLAZEPOSE_33.index(name)]

    def d(a: str, b: str) -> float:
        return float(np.linalg.norm(at(a) - at(b)))

    mid_hip = (at("left_hip") + at("right_hip")) / 2
    mid_shoulder = (at("left_shoulder") + at("right_shoulder")) / 2
    mid_ear = (at("left_ear") + at("right_ear")) / 2
    return {
        "trunk": float(np.linalg.norm(mid_shoulder - mid_hip)),
        "neck_to_head": float(np.linalg.norm(mid_ear - mid_shoulder)),
        "shoulder_width": d("left_shoulder", "right_shoulder"),
        "hip_width": d("left_hip", "right_hip"),
        **{
            f"{field}_{side}": d(f"{side}_{a}", f"{side}_{b}")
            for side in ("left", "right")
            for field, a, b in (
                ("upper_arm", "shoulder", "elbow"),
                ("forearm", "elbow", "wrist"),
                ("hand", "wrist", "index"),
                ("thigh", "hip", "knee"),
                ("shin", "knee", "ankle"),
                ("foot", "ankle", "foot_index"),
                ("heel", "ankle", "heel"),
            )
        },
    }


@pytest.mark.parametrize("bones", SIZES)
def test_fk_segments_equal_the_bone_lengths(bones: BoneLengths) -> None:
    model = _model(bones)
    rng = np.random.default_rng(0)
    # Lengths hold in any pose, not only at qpos0.
    for k, qpos in enumerate([model.qpos0.copy(), *_random_qpos(rng, 3)]):
        points = compiled.keypoint_positions(model, qpos)
        got = _measured(points)
        if k == 0:  # the abdomen's bend shortens the trunk in other poses
            assert got["trunk"] == pytest.approx(bones.pelvis_to_torso + bones.torso_to_neck)
        for name in ("neck_to_head", "shoulder_width", "hip_width"):
            assert got[name] == pytest.approx(getattr(bones, name)), name
        for side in ("left", "right"):
            for name in ("upper_arm", "forearm", "hand", "thigh", "shin", "foot", "heel"):
                assert got[f"{name}_{side}"] == pytest.approx(getattr(bones, name)), name
    assert bones.stature == pytest.approx(
        _model(bones).qpos0[2]
        + bones.pelvis_to_torso
        + bones.torso_to_neck
        + bones.neck_to_head
        + bones.head_radius
    )


def test_default_bones_are_an_adult_of_178_cm() -> None:
    assert BoneLengths().stature == pytest.approx(1.78, abs=0.01)
    assert BoneLengths().scaled(1.1).stature == pytest.approx(1.1 * BoneLengths().stature)


@pytest.mark.parametrize("bones", [SMALL, BoneLengths().scaled(1.08)])
def test_from_points_recovers_the_bones(bones: BoneLengths) -> None:
    model = _model(bones)
    rng = np.random.default_rng(1)
    qpos = _random_qpos(rng, 120)
    # A boxer's trunk bends a little, not over the abdomen's whole range.
    abdomen = next(j for j in K.JOINT_LAYOUT if j.name == "abdomen").qpos
    qpos[:, abdomen] = rng.uniform(-0.25, 0.25, (120, 3))
    points = compiled.keypoint_positions(model, qpos)
    points = points + rng.normal(0.0, 0.004, points.shape)  # 4 mm landmark noise
    points[::10] += rng.normal(0.0, 0.15, points[::10].shape)  # every 10th frame wild
    points[5, BLAZEPOSE_33.index("left_elbow")] = np.nan  # a missing landmark
    got = BoneLengths.from_points(points)
    for field in ("shoulder_width", "upper_arm", "forearm", "hand", "hip_width"):
        assert getattr(got, field) == pytest.approx(getattr(bones, field), abs=0.006), field
    for field in ("thigh", "shin", "foot", "heel", "ankle_height", "neck_to_head"):
        assert getattr(got, field) == pytest.approx(getattr(bones, field), abs=0.006), field
    trunk = bones.pelvis_to_torso + bones.torso_to_neck
    assert got.pelvis_to_torso + got.torso_to_neck == pytest.approx(trunk, abs=0.006)
    assert got.head_radius == pytest.approx(bones.head_radius, abs=0.008)
    # The fitted bones build a model whose skeleton matches the points.
    assert abs(got.stature - bones.stature) < 0.02


def test_from_points_needs_each_length_once() -> None:
    points = np.full((3, 33, 3), np.nan)
    with pytest.raises(ValueError, match="no 'upper_arm'|no 'trunk'"):
        BoneLengths.from_points(points)


def test_keypoint_maps_cover_both_formats() -> None:
    assert set(K.BLAZEPOSE_TO_SITE) == set(BLAZEPOSE_33)
    assert set(K.COCO17_TO_SITE) == set(COCO_17)
    assert set(K.BLAZEPOSE_TO_SITE.values()) <= set(K.SITE_NAMES)
    assert K.KEYPOINT_TO_BODY["left_wrist"] == "left_hand"
    assert K.KEYPOINT_TO_BODY["right_knee"] == "right_shin"
    assert K.KEYPOINT_TO_BODY["nose"] == "head"
    model = _model()
    coco = compiled.keypoint_positions(model, model.qpos0, keypoints=COCO_17)
    blaze = compiled.keypoint_positions(model, model.qpos0)
    np.testing.assert_allclose(coco, blaze[[BLAZEPOSE_33.index(n) for n in COCO_17]])
    # Left is +y and the nose points +x at rest.
    assert coco[COCO_17.index("left_shoulder"), 1] > 0 > coco[COCO_17.index("right_shoulder"), 1]
    assert coco[COCO_17.index("nose"), 0] > 0.05


# --------------------------------------------------------------------------
# Rotations and frames
# --------------------------------------------------------------------------


def test_tangent_normal_hand_computed() -> None:
    np.testing.assert_allclose(K.tangent_normal(np.eye(3)), [1, 0, 0, 0, 0, 1])
    quarter = math.pi / 2
    cases = {
        "z": [0, 1, 0, 0, 0, 1],  # x -> y, z stays
        "y": [0, 0, -1, 1, 0, 0],  # x -> -z, z -> x
        "x": [1, 0, 0, 0, -1, 0],  # x stays, z -> -y
    }
    for axis, expected in cases.items():
        rotation = K.axis_angle_matrix(K._AXES[axis], quarter)
        np.testing.assert_allclose(K.tangent_normal(rotation), expected, atol=1e-12)
    rotations = K.expmap_to_matrix(np.random.default_rng(2).normal(size=(50, 3)))
    np.testing.assert_allclose(K.tangent_normal_to_matrix(K.tangent_normal(rotations)), rotations)


def test_rotation_conversions_round_trip() -> None:
    rng = np.random.default_rng(4)
    rotations = K.expmap_to_matrix(rng.normal(size=(200, 3)))
    np.testing.assert_allclose(K.quat_to_matrix(K.matrix_to_quat(rotations)), rotations, atol=1e-12)
    quats = rng.normal(size=(200, 4))
    mine = K.quat_to_matrix(quats)
    for q, m in zip(quats, mine, strict=True):
        ref = np.empty(9)
        mujoco.mju_quat2Mat(ref, q / np.linalg.norm(q))
        np.testing.assert_allclose(m, ref.reshape(3, 3), atol=1e-12)
    np.testing.assert_allclose(K.expmap_to_matrix(K.matrix_to_expmap(rotations)), rotations)
    np.testing.assert_allclose(
        K.euler_yxz_to_matrix(K.matrix_to_euler_yxz(rotations)), rotations, atol=1e-12
    )
    # The singular middle angle still reconstructs the rotation.
    singular = K.euler_yxz_to_matrix(np.array([[0.4, math.pi / 2, -0.3], [1.0, -math.pi / 2, 0.2]]))
    np.testing.assert_allclose(
        K.euler_yxz_to_matrix(K.matrix_to_euler_yxz(singular)), singular, atol=1e-9
    )
    # Small and zero exp-maps.
    np.testing.assert_allclose(K.matrix_to_expmap(np.eye(3)), 0.0)
    tiny = np.array([1e-9, -2e-9, 3e-9])
    np.testing.assert_allclose(K.matrix_to_expmap(K.expmap_to_matrix(tiny)), tiny, atol=1e-15)


def test_mujoco_composes_hinges_as_kinematics_says() -> None:
    model = _model()
    qpos = _random_qpos(np.random.default_rng(5), 10)
    _, rot = compiled.forward_kinematics_batch(model, qpos)
    np.testing.assert_allclose(K.body_rotations(qpos), rot, atol=1e-12)


def test_qpos_from_body_rotations_inverts_fk() -> None:
    model = _model()
    qpos = _random_qpos(np.random.default_rng(6), 50)
    pos, rot = compiled.forward_kinematics_batch(model, qpos)
    back = K.qpos_from_body_rotations(pos[:, 0], rot)
    # Quaternions are equal up to sign.
    sign = np.sign(np.sum(back[:, 3:7] * qpos[:, 3:7], axis=1, keepdims=True))
    np.testing.assert_allclose(back[:, 3:7] * sign, qpos[:, 3:7], atol=1e-9)
    np.testing.assert_allclose(back[:, :3], qpos[:, :3], atol=1e-12)
    np.testing.assert_allclose(back[:, 7:], qpos[:, 7:], atol=1e-9)


def test_actions_map_to_hinge_targets_and_back() -> None:
    action = np.zeros(28)
    shoulder = next(j for j in K.JOINT_LAYOUT if j.name == "right_shoulder")
    action[shoulder.action] = [0.0, -1.2, 0.0]  # exp-map: -1.2 rad about y
    targets = K.action_to_joint_targets(action)
    np.testing.assert_allclose(targets[shoulder.action], [-1.2, 0.0, 0.0], atol=1e-12)
    elbow = next(j for j in K.JOINT_LAYOUT if j.name == "right_elbow")
    action[elbow.action] = 1.1
    assert K.action_to_joint_targets(action)[elbow.action] == pytest.approx(1.1)
    hinge = _random_qpos(np.random.default_rng(7), 20)[:, 7:]
    np.testing.assert_allclose(
        K.action_to_joint_targets(K.joint_targets_to_action(hinge)), hinge, atol=1e-9
    )


def test_torch_actions_get_the_same_targets_and_headings() -> None:
    # Warp's arena computes them on its device, from torch tensors: the same numbers. Tiny and
    # zero exponential maps included (Rodrigues' formula's series there), and angles past pi.
    import torch

    rng = np.random.default_rng(12)
    actions = rng.normal(0.0, 1.5, (200, 2, 28))
    actions[0, 0, :3], actions[1, 0, :3] = 0.0, 1e-7
    want = K.action_to_joint_targets(actions)
    got = K.action_to_joint_targets(torch.from_numpy(actions))
    assert isinstance(got, torch.Tensor)
    np.testing.assert_allclose(got.numpy(), want, atol=1e-12)
    quats = rng.normal(size=(50, 2, 4))
    yaw = K.heading_yaw(torch.from_numpy(quats))
    np.testing.assert_allclose(yaw.numpy(), K.heading_yaw(quats), atol=1e-12)


def test_heading_frame_is_yaw_only() -> None:
    rng = np.random.default_rng(8)
    quats = rng.normal(size=(30, 4))
    heading = K.heading_frame(quats)
    np.testing.assert_allclose(heading[:, 2], [[0, 0, 1]] * 30, atol=1e-12)
    np.testing.assert_allclose(
        heading @ np.swapaxes(heading, 1, 2), np.broadcast_to(np.eye(3), (30, 3, 3)), atol=1e-12
    )
    # Its x axis is the root's x axis projected on the floor.
    forward = K.quat_to_matrix(quats)[:, :, 0] * [1, 1, 0]
    forward /= np.linalg.norm(forward, axis=1, keepdims=True)
    np.testing.assert_allclose(heading[:, :, 0], forward, atol=1e-12)
    assert K.heading_yaw(_yaw_quat(0.7)) == pytest.approx(0.7)


def test_local_observations_ignore_translation_and_yaw() -> None:
    model = _model()
    rng = np.random.default_rng(9)
    qpos = _random_qpos(rng, 5)
    moved = qpos.copy()
    for frame in moved:
        turn = _yaw_quat(rng.uniform(-math.pi, math.pi))
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, turn)
        frame[:3] = rot.reshape(3, 3) @ frame[:3] + [rng.normal(), rng.normal(), 0.0]
        frame[3:7] = _quat_mul(turn, frame[3:7])
    pos, rot = compiled.forward_kinematics_batch(model, qpos)
    pos2, rot2 = compiled.forward_kinematics_batch(model, moved)
    local = K.local_body_positions(pos, qpos[:, :3], qpos[:, 3:7])
    local2 = K.local_body_positions(pos2, moved[:, :3], moved[:, 3:7])
    np.testing.assert_allclose(local, local2, atol=1e-9)
    np.testing.assert_allclose(local[:, 0], 0.0, atol=1e-12)
    tn = K.tangent_normal(K.local_body_rotations(rot, qpos[:, 3:7]))
    tn2 = K.tangent_normal(K.local_body_rotations(rot2, moved[:, 3:7]))
    np.testing.assert_allclose(tn, tn2, atol=1e-9)
    assert tn.shape == (5, 15, 6)
    # But it does see the root's pitch and roll.
    tilted = qpos.copy()
    tilted[:, 3:7] = [_quat_mul(q, [math.cos(0.2), math.sin(0.2), 0.0, 0.0]) for q in qpos[:, 3:7]]
    pos3, _ = compiled.forward_kinematics_batch(model, tilted)
    local3 = K.local_body_positions(pos3, tilted[:, :3], tilted[:, 3:7])
    assert np.abs(local3 - local).max() > 0.05


def test_forward_kinematics_batch_equals_per_frame() -> None:
    model = _model()
    qpos = _random_qpos(np.random.default_rng(10), 7)
    pos, rot = compiled.forward_kinematics_batch(model, qpos)
    assert pos.shape == (7, 15, 3) and rot.shape == (7, 15, 3, 3)
    for t in range(7):
        p, r = compiled.forward_kinematics(model, qpos[t])
        np.testing.assert_array_equal(p, pos[t])
        np.testing.assert_array_equal(r, rot[t])
    points = compiled.keypoint_positions(model, qpos)
    np.testing.assert_array_equal(points[3], compiled.keypoint_positions(model, qpos[3]))
    # Bodies sit at their sites: the left elbow body at the left elbow site.
    elbow = K.BODY_NAMES.index("left_lower_arm")
    np.testing.assert_allclose(pos[:, elbow], points[:, BLAZEPOSE_33.index("left_elbow")])
