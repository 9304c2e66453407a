"""DeepMimic's imitation reward and the tracker's errors: pure, batched functions of body states.

Errors (`body_error`, `root_error`): the mean over the 15 bodies of the distance between the
simulated and the reference body origins, each relative to its own pelvis (world axes, so a
turned body counts), and the distance between the pelvises.

Shape letters: B bodies (15); every function takes any leading shape (...).
"""

from __future__ import annotations

import numpy as np

from models.humanoid.kinematics import BODY_NAMES, PARENTS, heading_frame_of_matrix
from models.humanoid.observations import BodyState
from models.tracking.config import TrackConfig

# The bodies whose joints the pose and velocity terms sum over: all but the hands, welded to
# the forearms. The pelvis's "joint" is its rotation (and angular velocity) in the world.
JOINT_BODIES = np.array([i for i, b in enumerate(BODY_NAMES) if not b.endswith("_hand")])
END_EFFECTORS = np.array(
    [BODY_NAMES.index(b) for b in ("right_hand", "left_hand", "right_foot", "left_foot")]
)
REWARD_TERMS = ("pose", "velocity", "end_effector", "com")
_PARENT = np.array([max(p, 0) for p in PARENTS])


def centre_of_mass(state: BodyState, body_mass: np.ndarray, body_com: np.ndarray) -> np.ndarray:
    """(..., 3) the whole humanoid's centre of mass from its bodies' poses, masses (15,) and
    local centres of mass (15, 3) (MuJoCo's body_mass and body_ipos)."""
    points = state.pos + np.einsum("...ij,...j->...i", state.rot, body_com)
    return np.einsum("...bi,b->...i", points, body_mass) / body_mass.sum()


def joint_rotations(state: BodyState) -> np.ndarray:
    """(..., 13, 3, 3) each JOINT_BODIES body's rotation in its parent's frame, the pelvis's in
    the world's."""
    local = state.rot[..., _PARENT, :, :].swapaxes(-1, -2) @ state.rot
    local[..., 0, :, :] = state.rot[..., 0, :, :]
    return local[..., JOINT_BODIES, :, :]


def joint_velocities(state: BodyState) -> np.ndarray:
    """(..., 13, 3) each JOINT_BODIES body's angular velocity relative to its parent, in the
    parent's frame; the pelvis's in the world."""
    relative = state.ang_vel - state.ang_vel[..., _PARENT, :]
    local = np.einsum("...bji,...bj->...bi", state.rot[..., _PARENT, :, :], relative)
    local[..., 0, :] = state.ang_vel[..., 0, :]
    return local[..., JOINT_BODIES, :]


def end_effector_positions(state: BodyState) -> np.ndarray:
    """(..., 4, 3) hands and feet relative to the pelvis in its heading frame, with z their
    height above the floor (as DeepMimic's code measures them)."""
    heading = heading_frame_of_matrix(state.rot[..., 0, :, :])
    ends = state.pos[..., END_EFFECTORS, :]
    relative = (ends - state.pos[..., 0:1, :]) @ heading
    relative[..., 2] = ends[..., 2]
    return relative


def rotation_angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(...) the angle (rad) of the rotation between rotation matrices a and b (..., 3, 3):
    2 asin(|a - b|_F / sqrt 8), exact near 0 where acos of the trace is not."""
    frobenius = np.sqrt(np.sum((a - b) ** 2, axis=(-2, -1)))
    return 2 * np.arcsin(np.clip(frobenius / np.sqrt(8.0), 0.0, 1.0))


def deepmimic_reward(
    sim: BodyState,
    ref: BodyState,
    sim_com: np.ndarray,
    ref_com: np.ndarray,
    *,
    config: TrackConfig,
) -> dict[str, np.ndarray]:
    """DeepMimic's imitation reward (Peng et al. 2018) of states ``sim`` against ``ref``.

    r = w_p r_p + w_v r_v + w_e r_e + w_c r_c with
    r_p = exp(-2 sum_j angle(q_j, q^_j)^2)   joint rotations (`joint_rotations`),
    r_v = exp(-0.1 sum_j |w_j - w^_j|^2)     joint angular velocities (`joint_velocities`),
    r_e = exp(-40 sum_e |p_e - p^_e|^2)      hands and feet (`end_effector_positions`),
    r_c = exp(-10 |p_c - p^_c|^2)            centre of mass (world),
    weights 0.65, 0.1, 0.15, 0.1 and the scales above by default (`TrackConfig`).

    Args:
        sim, ref: BodyState of leading shape (...).
        sim_com, ref_com: (..., 3) their centres of mass (`centre_of_mass`).

    Returns:
        {"pose", "velocity", "end_effector", "com", "total"}: each (...).
    """
    pose = np.sum(rotation_angles(joint_rotations(sim), joint_rotations(ref)) ** 2, axis=-1)
    velocity = np.sum((joint_velocities(sim) - joint_velocities(ref)) ** 2, axis=(-2, -1))
    ends = np.sum((end_effector_positions(sim) - end_effector_positions(ref)) ** 2, axis=(-2, -1))
    com = np.sum((np.asarray(sim_com) - np.asarray(ref_com)) ** 2, axis=-1)
    terms = {
        "pose": np.exp(-config.pose_scale * pose),
        "velocity": np.exp(-config.velocity_scale * velocity),
        "end_effector": np.exp(-config.end_effector_scale * ends),
        "com": np.exp(-config.com_scale * com),
    }
    terms["total"] = (
        config.w_pose * terms["pose"]
        + config.w_velocity * terms["velocity"]
        + config.w_end_effector * terms["end_effector"]
        + config.w_com * terms["com"]
    )
    return terms


def body_error(sim: BodyState, ref: BodyState) -> np.ndarray:
    """(...) mean distance (m) over the 15 bodies between ``sim``'s and ``ref``'s body origins,
    each relative to its own pelvis (world axes)."""
    relative_sim = sim.pos - sim.pos[..., 0:1, :]
    relative_ref = ref.pos - ref.pos[..., 0:1, :]
    return np.linalg.norm(relative_sim - relative_ref, axis=-1).mean(-1)


def root_error(sim: BodyState, ref: BodyState) -> np.ndarray:
    """(...) distance (m) between the two pelvises."""
    return np.linalg.norm(sim.pos[..., 0, :] - ref.pos[..., 0, :], axis=-1)
