"""The agents' observations, MAAIP §4.2: one function for demonstrations and simulation alike.

The dataset stage computes demonstration transitions with these functions and the training
environment computes the simulated ones with the same functions, so the discriminators compare
like with like. Both start from a :class:`BodyState`, read from MuJoCo by
:func:`models.humanoid.compiled.body_state` (a running simulation) or
:func:`models.humanoid.compiled.body_states` (a recorded motion's qpos and qvel).

Blocks and sizes (the paper gives 274 in all):

o^self (223), in the agent's heading frame (origin at the pelvis, x along its facing direction
on the floor, z up; `models.humanoid.kinematics.heading_frame_of_matrix`):

=========================  ====  ==========================================================
root_height                   1  pelvis height above the floor (z = 0)
body_positions               42  the 14 non-root bodies' origins relative to the pelvis
body_rotations               90  15 bodies x [tangent, normal] (`tangent_normal`), each body
                                 in its parent's frame, the pelvis in the heading frame
body_linear_velocities       45  15 bodies' origin velocities
body_angular_velocities      45  15 bodies' angular velocities
=========================  ====  ==========================================================

o^opp (51), about the opponent, in the agent's heading frame:

=========================  ====  ==========================================================
root_position                 3  opponent pelvis relative to the agent's pelvis
root_rotation                 6  opponent pelvis rotation as [tangent, normal]
root_linear_velocity          3
root_angular_velocity         3
key_body_positions           18  head, torso, hands, feet (`KEY_BODIES`) relative to the
                                 agent's pelvis
key_body_velocities          18  their linear velocities
=========================  ====  ==========================================================

The paper lists the self velocities as one block of 45; its total of 274 needs both linear
and angular velocities of all 15 bodies (45 each), which is what it says in words and what
is computed here. Its opponent velocities likewise hold linear and angular (3 each).

Every function takes NumPy arrays or torch tensors (on any device) alike, so the training
arena can observe on the GPU with the very function the dataset uses (`models.arena.stepping.warp`).

Shape letters: T frames (or any leading batch shape), N = 15 bodies.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from array_api_compat import array_namespace, device

from models.humanoid.kinematics import (
    KEY_BODY_INDEX,
    NUM_BODIES,
    PARENTS,
    heading_frame_of_matrix,
    matrix_to_quat,
    tangent_normal,
)

if TYPE_CHECKING:  # annotations only: reading a simulation needs no MuJoCo import here
    import mujoco


SELF_BLOCKS: tuple[tuple[str, int], ...] = (
    ("root_height", 1),
    ("body_positions", 3 * (NUM_BODIES - 1)),
    ("body_rotations", 6 * NUM_BODIES),
    ("body_linear_velocities", 3 * NUM_BODIES),
    ("body_angular_velocities", 3 * NUM_BODIES),
)
OPPONENT_BLOCKS: tuple[tuple[str, int], ...] = (
    ("root_position", 3),
    ("root_rotation", 6),
    ("root_linear_velocity", 3),
    ("root_angular_velocity", 3),
    ("key_body_positions", 3 * len(KEY_BODY_INDEX)),
    ("key_body_velocities", 3 * len(KEY_BODY_INDEX)),
)
SELF_DIM = sum(size for _, size in SELF_BLOCKS)  # 223
OPPONENT_DIM = sum(size for _, size in OPPONENT_BLOCKS)  # 51
OBSERVATION_DIM = SELF_DIM + OPPONENT_DIM  # 274, as in the paper
assert (SELF_DIM, OPPONENT_DIM, OBSERVATION_DIM) == (223, 51, 274)

_PARENT_INDEX = [max(p, 0) for p in PARENTS]


def block_slices(blocks: tuple[tuple[str, int], ...], start: int = 0) -> dict[str, slice]:
    """Where each named block lies in an observation vector."""
    slices = {}
    for name, size in blocks:
        slices[name] = slice(start, start + size)
        start += size
    return slices


@dataclass(frozen=True, eq=False)
class BodyState:
    """One humanoid's 15 bodies in the world: origins, rotations and their velocities.

    Attributes:
        pos: (..., 15, 3) body origins in metres (the pelvis origin is the root position).
        rot: (..., 15, 3, 3) body rotations (MuJoCo's xmat).
        lin_vel: (..., 15, 3) velocities of the body origins, m/s.
        ang_vel: (..., 15, 3) angular velocities, rad/s, world axes.
    """

    pos: np.ndarray
    rot: np.ndarray
    lin_vel: np.ndarray
    ang_vel: np.ndarray

    def __post_init__(self) -> None:
        lead = self.pos.shape[:-2]
        shapes = {
            "pos": (self.pos.shape, (*lead, NUM_BODIES, 3)),
            "rot": (self.rot.shape, (*lead, NUM_BODIES, 3, 3)),
            "lin_vel": (self.lin_vel.shape, (*lead, NUM_BODIES, 3)),
            "ang_vel": (self.ang_vel.shape, (*lead, NUM_BODIES, 3)),
        }
        for name, (got, want) in shapes.items():
            if got != want:
                raise ValueError(f"BodyState.{name} must have shape {want}, got {got}")

    @property
    def root_quat(self) -> np.ndarray:
        """(..., 4) pelvis quaternions (w, x, y, z)."""
        return matrix_to_quat(self.rot[..., 0, :, :])

    def __getitem__(self, index) -> BodyState:
        """The state at some leading (time or batch) indices."""
        return BodyState(self.pos[index], self.rot[index], self.lin_vel[index], self.ang_vel[index])


def stacked(states: Sequence[BodyState], axis: int = 1) -> BodyState:
    """Several humanoids' states (each (B,)) as one, stacked on ``axis``: (B, 2) for both
    fighters of a batch of arenas."""
    return BodyState(
        *(
            np.stack([getattr(s, name) for s in states], axis=axis)
            for name in ("pos", "rot", "lin_vel", "ang_vel")
        )
    )


FRAME_WIDTH = 21  # world_frames' columns


def world_frames(
    model: mujoco.MjModel, data: mujoco.MjData, out: np.ndarray | None = None
) -> np.ndarray:
    """The raw arrays `body_state_from_frames` reads, copied from one MjData.

    `data` must hold positions and velocities computed by MuJoCo (after `mj_step` or
    `mj_forward`, or at least `mj_kinematics`, `mj_comPos` and `mj_comVel`).

    Args:
        model, data: the simulation.
        out: optional (nbody, FRAME_WIDTH) array to fill, e.g. a row of a batch.

    Returns:
        (nbody, 21): per model body xpos (3), xmat (9), cvel (6) and the subtree_com of its
        kinematic tree's root (3).
    """
    if out is None:
        out = np.empty((model.nbody, FRAME_WIDTH))
    out[:, 0:3] = data.xpos
    out[:, 3:12] = data.xmat
    out[:, 12:18] = data.cvel
    out[:, 18:21] = data.subtree_com[model.body_rootid]
    return out


def body_state_from_frames(frames: np.ndarray, body_ids: np.ndarray) -> BodyState:
    """Humanoid body states from `world_frames` rows, for any batch of simulations and humanoids.

    Args:
        frames: (..., nbody, 21) from `world_frames`.
        body_ids: (15,) model body ids of one humanoid's bodies (`HumanoidIndex.body_ids`), or
            (A, 15) of A humanoids in the same model (the two fighters of an arena).

    Returns:
        BodyState with leading shape frames' leading shape, then A if body_ids has it.
    """
    xp = array_namespace(frames)
    picked = frames[..., xp.asarray(body_ids, device=device(frames)), :]
    pos = picked[..., 0:3]
    rot = xp.reshape(picked[..., 3:12], (*picked.shape[:-1], 3, 3))
    # cvel is [angular, linear] at the centre of mass of the body's kinematic tree
    # (subtree_com of its root body), world axes; move the linear part to each body origin.
    ang = picked[..., 12:15]
    r = pos - picked[..., 18:21]
    # ang x r written out: np.cross costs more than a physics step at this size (measured).
    lin = xp.asarray(picked[..., 15:18], copy=True)
    lin[..., 0] += ang[..., 1] * r[..., 2] - ang[..., 2] * r[..., 1]
    lin[..., 1] += ang[..., 2] * r[..., 0] - ang[..., 0] * r[..., 2]
    lin[..., 2] += ang[..., 0] * r[..., 1] - ang[..., 1] * r[..., 0]
    return BodyState(pos, rot, lin, xp.asarray(ang, copy=True))


def in_heading(heading: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """(..., M, 3) world vectors in the heading frame `heading` (..., 3, 3): each row v
    becomes H.T v, i.e. the rows times H (matmul is 2-3x faster than einsum here)."""
    return vectors @ heading


def _flat(values: np.ndarray, trailing: int) -> np.ndarray:
    return array_namespace(values).reshape(values, (*values.shape[: values.ndim - trailing], -1))


def self_observation(state: BodyState) -> np.ndarray:
    """o^self: (..., 223), the blocks of `SELF_BLOCKS` in order."""
    heading = heading_frame_of_matrix(state.rot[..., 0, :, :])
    root = state.pos[..., 0, :]
    positions = in_heading(heading, state.pos[..., 1:, :] - root[..., None, :])
    parent_rot = state.rot[..., _PARENT_INDEX, :, :]
    local = parent_rot.swapaxes(-1, -2) @ state.rot
    local[..., 0, :, :] = heading.swapaxes(-1, -2) @ state.rot[..., 0, :, :]
    return array_namespace(root).concat(
        [
            root[..., 2:3],
            _flat(positions, 2),
            _flat(tangent_normal(local), 2),
            _flat(in_heading(heading, state.lin_vel), 2),
            _flat(in_heading(heading, state.ang_vel), 2),
        ],
        axis=-1,
    )


def opponent_observation(state: BodyState, opponent: BodyState) -> np.ndarray:
    """o^opp: (..., 51), what the agent in `state` observes of `opponent` (`OPPONENT_BLOCKS`)."""
    heading = heading_frame_of_matrix(state.rot[..., 0, :, :])
    root = state.pos[..., 0, :]
    relative = opponent.pos[..., [0, *KEY_BODY_INDEX], :] - root[..., None, :]
    positions = in_heading(heading, relative)
    velocities = in_heading(heading, opponent.lin_vel[..., [0, *KEY_BODY_INDEX], :])
    opponent_rot = heading.swapaxes(-1, -2) @ opponent.rot[..., 0, :, :]
    opponent_ang = in_heading(heading, opponent.ang_vel[..., 0:1, :])
    return array_namespace(root).concat(
        [
            positions[..., 0, :],
            tangent_normal(opponent_rot),
            velocities[..., 0, :],
            opponent_ang[..., 0, :],
            _flat(positions[..., 1:, :], 2),
            _flat(velocities[..., 1:, :], 2),
        ],
        axis=-1,
    )


def observation(state: BodyState, opponent: BodyState) -> np.ndarray:
    """o = [o^self, o^opp]: (..., 274)."""
    parts = [self_observation(state), opponent_observation(state, opponent)]
    return array_namespace(*parts).concat(parts, axis=-1)
