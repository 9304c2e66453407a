"""The MAAIP observation features (models.humanoid.observations): values, invariances, sizes."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import models.arena.env as train_env
import models.arena.stepping.host as host_worlds
import tasks.dataset.stage as dataset_stage
from models.humanoid import compiled
from models.humanoid import observations as obs
from models.humanoid.boxer import JOINT_RANGES_DEG, BoneLengths, boxer_mjcf
from models.humanoid.compiled import humanoid_index
from models.humanoid.kinematics import (
    BODY_NAMES,
    HINGE_NAMES,
    axis_angle_matrix,
    matrix_to_quat,
    quat_to_matrix,
)

BONES = BoneLengths()


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(boxer_mjcf(BONES))


def _yaw_quat(yaw: float) -> np.ndarray:
    return matrix_to_quat(axis_angle_matrix((0, 0, 1), yaw))


def _state(model, qpos, qvel) -> obs.BodyState:
    return compiled.body_states(model, qpos[None], qvel[None], humanoid_index(model))[0]


def _standing(model, position, yaw) -> np.ndarray:
    q = model.qpos0.copy()
    q[:3] = position
    q[3:7] = _yaw_quat(yaw)
    return q


def test_dimensions_are_the_papers():
    assert [size for _, size in obs.SELF_BLOCKS] == [1, 42, 90, 45, 45]
    assert [size for _, size in obs.OPPONENT_BLOCKS] == [3, 6, 3, 3, 18, 18]
    assert (obs.SELF_DIM, obs.OPPONENT_DIM, obs.OBSERVATION_DIM) == (223, 51, 274)
    slices = obs.block_slices(obs.SELF_BLOCKS + obs.OPPONENT_BLOCKS)
    assert slices["root_height"] == slice(0, 1)
    assert slices["key_body_velocities"] == slice(256, 274)


def test_the_training_environment_shares_the_dataset_features():
    # The dataset stage and the training environment call these very functions (not copies).
    assert dataset_stage.observation is obs.observation
    assert dataset_stage.self_observation is obs.self_observation
    assert dataset_stage.body_states is compiled.body_states
    assert train_env.observation is obs.observation
    assert train_env.body_state_from_frames is obs.body_state_from_frames
    assert host_worlds.world_frames is obs.world_frames


def test_hand_built_standing_pose(model):
    """Standing at rest, turned to face +y and spinning about z: every block by hand."""
    yaw, spin, speed = np.pi / 2, 0.5, 1.5
    q = _standing(model, (1.0, 2.0, 0.955), yaw)
    v = np.zeros(model.nv)
    v[:3] = (speed, 0.0, 0.0)  # world frame: to the fighter's right when it faces +y
    v[5] = spin  # about the pelvis z axis (= world z for a yaw-only root)
    o = obs.self_observation(_state(model, q, v))
    s = obs.block_slices(obs.SELF_BLOCKS)

    assert o[s["root_height"]] == pytest.approx([0.955])
    # Rest offsets of the bodies from the pelvis (see BoneLengths), in the heading frame.
    neck = BONES.pelvis_to_torso + BONES.torso_to_neck
    half = BONES.shoulder_width / 2
    positions = o[s["body_positions"]].reshape(14, 3)
    expected = {
        "torso": (0, 0, BONES.pelvis_to_torso),
        "head": (0, 0, neck),
        "right_upper_arm": (0, -half, neck),
        "left_lower_arm": (0, half, neck - BONES.upper_arm),
        "left_foot": (0, BONES.hip_width / 2, -BONES.thigh - BONES.shin),
    }
    for body, value in expected.items():
        np.testing.assert_allclose(positions[BODY_NAMES.index(body) - 1], value, atol=1e-9)
    # Every body at rest: identity, the tangent x and the normal z.
    rotations = o[s["body_rotations"]].reshape(15, 6)
    np.testing.assert_allclose(rotations, np.tile([1, 0, 0, 0, 0, 1], (15, 1)), atol=1e-9)
    # World +x is the heading frame's -y; the spin adds w z x r to each body origin.
    linear = o[s["body_linear_velocities"]].reshape(15, 3)
    np.testing.assert_allclose(linear[0], (0, -speed, 0), atol=1e-9)
    arm = BODY_NAMES.index("right_upper_arm")
    np.testing.assert_allclose(linear[arm], (spin * half, -speed, 0), atol=1e-9)
    angular = o[s["body_angular_velocities"]].reshape(15, 3)
    np.testing.assert_allclose(angular, np.tile([0, 0, spin], (15, 1)), atol=1e-9)


def test_hand_built_opponent(model):
    """The opponent 2 m in front, facing back and stepping in at 1 m/s."""
    me = _state(model, _standing(model, (1.0, 2.0, 0.955), np.pi / 2), np.zeros(model.nv))
    v = np.zeros(model.nv)
    v[1] = -1.0  # towards me (world -y)
    them = _state(model, _standing(model, (1.0, 4.0, 0.9), -np.pi / 2), v)
    o = obs.opponent_observation(me, them)
    s = obs.block_slices(obs.OPPONENT_BLOCKS)
    np.testing.assert_allclose(o[s["root_position"]], (2, 0, -0.055), atol=1e-9)
    np.testing.assert_allclose(o[s["root_rotation"]], (-1, 0, 0, 0, 0, 1), atol=1e-9)
    np.testing.assert_allclose(o[s["root_linear_velocity"]], (-1, 0, 0), atol=1e-9)
    np.testing.assert_allclose(o[s["root_angular_velocity"]], (0, 0, 0), atol=1e-9)
    # Their head is above their pelvis; turned round, their right hand is on my left (+y).
    keys = o[s["key_body_positions"]].reshape(6, 3)
    neck = BONES.pelvis_to_torso + BONES.torso_to_neck
    np.testing.assert_allclose(keys[0], (2, 0, neck - 0.055), atol=1e-9)
    np.testing.assert_allclose(
        keys[2],
        (2, BONES.shoulder_width / 2, neck - BONES.upper_arm - BONES.forearm - 0.055),
        atol=1e-9,
    )
    np.testing.assert_allclose(
        o[s["key_body_velocities"]].reshape(6, 3), np.tile([-1, 0, 0], (6, 1)), atol=1e-9
    )
    full = obs.observation(me, them)
    assert full.shape == (274,)
    np.testing.assert_array_equal(full[223:], o)


def _random_pose(model, rng) -> tuple[np.ndarray, np.ndarray]:
    q = model.qpos0.copy()
    q[:3] = rng.uniform(-2, 2, 3) + (0, 0, 1)
    tilt = axis_angle_matrix(rng.normal(size=3), rng.uniform(0, 0.3))
    q[3:7] = matrix_to_quat(axis_angle_matrix((0, 0, 1), rng.uniform(-np.pi, np.pi)) @ tilt)
    limits = np.radians([JOINT_RANGES_DEG[h] for h in HINGE_NAMES])
    q[7:] = rng.uniform(limits[:, 0], limits[:, 1])
    return q, rng.normal(size=model.nv)


def _moved(q, v, turn, shift):
    """The same motion seen after turning the world by `turn` about z and shifting it by `shift`."""
    turn_m = axis_angle_matrix((0, 0, 1), turn)
    q, v = q.copy(), v.copy()
    q[:3] = turn_m @ q[:3] + shift
    q[3:7] = matrix_to_quat(turn_m @ quat_to_matrix(q[3:7]))
    v[:3] = turn_m @ v[:3]  # world frame; the angular part is in the pelvis frame
    return q, v


def test_features_ignore_where_the_pair_stands_and_faces(model):
    rng = np.random.default_rng(7)
    for _ in range(5):
        (qa, va), (qb, vb) = _random_pose(model, rng), _random_pose(model, rng)
        before = obs.observation(_state(model, qa, va), _state(model, qb, vb))
        turn, shift = rng.uniform(-np.pi, np.pi), np.r_[rng.uniform(-5, 5, 2), 0.0]
        after = obs.observation(
            _state(model, *_moved(qa, va, turn, shift)), _state(model, *_moved(qb, vb, turn, shift))
        )
        np.testing.assert_allclose(after, before, atol=1e-9)
        # ...but not where each stands relative to the other.
        apart = obs.observation(
            _state(model, qa, va), _state(model, *_moved(qb, vb, 0.0, np.array([0.5, 0, 0])))
        )
        assert np.abs(apart - before)[223:].max() > 0.1


def test_body_velocities_match_mujoco(model):
    """The velocities read from cvel equal MuJoCo's own velocities of the body frames."""
    rng = np.random.default_rng(3)
    q, v = _random_pose(model, rng)
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = q, v
    mujoco.mj_forward(model, data)
    state = compiled.body_state(model, data, humanoid_index(model))
    velocity = np.zeros(6)
    for k, body in enumerate(humanoid_index(model).body_ids):
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_XBODY, body, velocity, 0)
        np.testing.assert_allclose(state.ang_vel[k], velocity[:3], atol=1e-9)
        np.testing.assert_allclose(state.lin_vel[k], velocity[3:], atol=1e-9)


def _random_states(model, seed: int) -> obs.BodyState:
    """Four random poses moving at random velocities."""
    rng = np.random.default_rng(seed)
    poses = [_random_pose(model, rng) for _ in range(4)]
    q = np.stack([p[0] for p in poses])
    v = np.stack([p[1] for p in poses])
    return compiled.body_states(model, q, v, humanoid_index(model))


def test_batched_features_equal_one_at_a_time(model):
    states = _random_states(model, 11)
    batch = obs.observation(states, states[::-1])
    for t in range(4):
        np.testing.assert_allclose(batch[t], obs.observation(states[t], states[3 - t]))


def test_torch_tensors_get_the_same_features(model):
    # The arena on MuJoCo Warp observes on its device with these functions, given tensors.
    import torch

    states = _random_states(model, 12)
    want = obs.observation(states, states[::-1])
    for dtype, tol in ((torch.float64, 1e-12), (torch.float32, 1e-5)):
        tensors = [torch.as_tensor(x, dtype=dtype) for x in (states.pos, states.rot)]
        tensors += [torch.as_tensor(x, dtype=dtype) for x in (states.lin_vel, states.ang_vel)]
        state = obs.BodyState(*tensors)
        got = obs.observation(state, state[[3, 2, 1, 0]])
        assert isinstance(got, torch.Tensor) and got.dtype == dtype
        np.testing.assert_allclose(got.numpy(), want, atol=tol)


def test_bad_shapes_are_named(model):
    with pytest.raises(ValueError, match="qvel must have shape"):
        compiled.body_states(model, model.qpos0[None], np.zeros((1, 3)), humanoid_index(model))
    with pytest.raises(ValueError, match="BodyState.rot"):
        obs.BodyState(np.zeros((15, 3)), np.zeros((15, 3)), np.zeros((15, 3)), np.zeros((15, 3)))
