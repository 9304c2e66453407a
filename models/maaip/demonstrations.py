"""What MAAIP learns from and starts episodes in: demonstrations and reference frames.

- :class:`ReferenceMotions` (`models.arena.starts`, where the arena starts episodes from it):
  interaction frames of both fighters in one world frame, to start episodes from (reference
  state initialisation); :func:`facing_reference` makes one from a single motion clip performed
  by two fighters facing each other.
- :class:`Demonstrations`: a dataset ready for training: the motion prior's single-actor
  transitions, each interaction prior's transitions, the reference frames and the two
  fighters' bones (`tasks.dataset.demonstrations.load_demonstrations` reads one from DuckDB;
  :func:`demonstrations_from_reference` computes one from arrays).

Shape letters: M frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from models.arena.starts import ReferenceMotions
from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.compiled import body_states, humanoid_index
from models.humanoid.kinematics import (
    NQ,
    NV,
    ROOT_POS,
    ROOT_QUAT,
    axis_angle_matrix,
    heading_frame,
    matrix_to_quat,
    quat_to_matrix,
)
from models.humanoid.observations import SELF_DIM, observation


def facing_reference(
    qpos: np.ndarray, qvel: np.ndarray, *, distance: float = 1.2
) -> ReferenceMotions:
    """A synthetic interaction for tests and benchmarks: one motion performed by both fighters.

    Agent 0 performs the motion as given; agent 1 performs it turned half a circle about the
    vertical axis through the point `distance` / 2 in front of agent 0's pelvis at the first
    frame, so that it starts `distance` in front of agent 0, facing it.

    Args:
        qpos: (M, 35) one fighter's qpos (e.g. a retargeted DeepMimic clip).
        qvel: (M, 34) its qvel.
        distance: pelvis-to-pelvis distance at the first frame, metres.

    Returns:
        The pair as ReferenceMotions.
    """
    q = np.array(qpos, dtype=np.float64)
    v = np.array(qvel, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != NQ:
        raise ValueError(f"qpos must have shape (M, {NQ}), got {q.shape}")
    if v.shape != (len(q), NV):
        raise ValueError(f"qvel must have shape ({len(q)}, {NV}), got {v.shape}")
    if not (math.isfinite(distance) and distance > 0):
        raise ValueError(f"distance must be a positive number of metres, got {distance!r}")
    turn = axis_angle_matrix((0.0, 0.0, 1.0), math.pi)
    facing = heading_frame(q[0, ROOT_QUAT])[:, 0]
    axis = q[0, ROOT_POS] + distance / 2 * facing
    axis[2] = 0.0
    q1, v1 = q.copy(), v.copy()
    q1[:, ROOT_POS] = (q[:, ROOT_POS] - axis) @ turn.T + axis
    q1[:, ROOT_QUAT] = matrix_to_quat(turn @ quat_to_matrix(q[:, ROOT_QUAT]))
    # The root's linear velocity is in the world frame and turns with it; its angular velocity
    # is in the pelvis frame (MuJoCo's free joint) and the hinge rates are local: unchanged.
    v1[:, 0:3] = v[:, 0:3] @ turn.T
    return ReferenceMotions(qpos0=q, qvel0=v, qpos1=q1, qvel1=v1)


@dataclass(frozen=True, eq=False)
class Demonstrations:
    """One dataset, ready for training.

    Attributes:
        dataset_key: the dataset's key.
        motion: (M, 446) single-actor transitions [o^self_t, o^self_t+1] (M^S).
        interaction: per agent, (M_i, 497) transitions [o_t, o^self_t+1] (agent i's side of M^I).
        reference: interaction frames of both fighters to start episodes from.
        bones: the adversary's and the opponent's bone lengths (agents 0 and 1).
        held_out: held-out transitions to judge the discriminators on, never learned from
            (the dataset's validation split): D^M's, then each D^I's, like ``motion`` and
            ``interaction``; empty where the split has none.
    """

    dataset_key: str
    motion: np.ndarray
    interaction: tuple[np.ndarray, np.ndarray]
    reference: ReferenceMotions
    bones: tuple[BoneLengths, BoneLengths]
    held_out: tuple[np.ndarray, ...] = ()


def demonstrations_from_reference(
    reference: ReferenceMotions, bones: tuple[BoneLengths, BoneLengths], *, key: str
) -> Demonstrations:
    """Demonstrations made from one interaction given as arrays, without a database.

    The transitions are computed as the dataset stage computes them (the shared observation
    functions on each fighter's own humanoid); both fighters' motions form the single-actor
    set. For benchmarks and tests that train on a motion clip, e.g. `facing_reference`.
    """
    states = []
    for agent, (qpos, qvel) in enumerate(
        ((reference.qpos0, reference.qvel0), (reference.qpos1, reference.qvel1))
    ):
        model = mujoco.MjModel.from_xml_string(boxer_mjcf(bones[agent]))
        states.append(body_states(model, qpos, qvel, humanoid_index(model)))
    obs = [observation(states[0], states[1]), observation(states[1], states[0])]
    motion = np.concatenate([np.concatenate([o[:-1, :SELF_DIM], o[1:, :SELF_DIM]], 1) for o in obs])
    interaction = tuple(
        np.concatenate([o[:-1], o[1:, :SELF_DIM]], 1).astype(np.float32) for o in obs
    )
    return Demonstrations(key, motion.astype(np.float32), interaction, reference, bones)
