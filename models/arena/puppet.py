"""A puppet (`Puppet`, for live sparring): one agent moved through given poses instead of by its
actuators.

Before every substep its qpos and qvel are set on the path from where it is to the step's pose
at constant velocity (`mj_differentiatePos`, `mj_integratePos`), and after the last it is
exactly at that pose; the solver still computes its contacts, so the other fighter is pushed
and struck by it, and damage and falls are read as for any agent. A puppet by the root only has
its pelvis moved so, and its limbs driven by its actions as usual. Only "threads" stepping takes
one ("rollout" steps in C without a hook between substeps, "warp" on the device): the others
raise `NEEDS_THREADS`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from models.arena.mjcf import ArenaIndex
from models.humanoid.kinematics import NQ

NEEDS_THREADS = 'a puppet needs EnvConfig.stepping "threads"'
# The puppet's qpos and qvel slices, the whole model's qpos at the step's start (N, nq) and the
# puppet's velocity to its pose (N, nv), per environment (`puppet_paths`).
PuppetPaths = tuple[slice, slice, np.ndarray, np.ndarray]


@dataclass(frozen=True, eq=False)
class Puppet:
    """An agent moved kinematically for one `ArenaEnv.step` (module docstring).

    Attributes:
        agent: which agent (0 or 1).
        qpos: (N, 35) its pose at the end of the step, per environment (a jump is `place`'s).
        root_only: move only its pelvis (the free joint) so; its hinges follow its actions
            through the actuators, as any agent's do.
    """

    agent: int
    qpos: np.ndarray
    root_only: bool = False


def puppet_paths(
    model: mujoco.MjModel,
    index: ArenaIndex,
    datas: Sequence[mujoco.MjData],
    puppet: Puppet,
    step_s: float,
) -> PuppetPaths:
    """The puppet's qpos and qvel slices, and per environment the whole model's qpos at the
    step's start (N, nq) and a qvel (N, nv) that is the puppet's velocity to its pose, reached
    after ``step_s`` seconds, from the N worlds ``datas`` as the step starts."""
    num_envs = len(datas)
    if puppet.agent not in (0, 1):
        raise ValueError(f"puppet.agent must be 0 or 1, got {puppet.agent!r}")
    qpos = np.asarray(puppet.qpos, dtype=np.float64)
    if qpos.shape != (num_envs, NQ) or not np.isfinite(qpos).all():
        raise ValueError(f"puppet.qpos must be finite with shape ({num_envs}, {NQ})")
    agent = index.agents[puppet.agent]
    moved_qpos, moved_qvel = agent.qpos, agent.qvel
    if puppet.root_only:
        moved_qpos = slice(agent.qpos_start, agent.qpos_start + 7)
        moved_qvel = slice(agent.qvel_start, agent.qvel_start + 6)
    starts = np.empty((num_envs, model.nq))
    velocities = np.zeros((num_envs, model.nv))
    for i, data in enumerate(datas):
        starts[i] = data.qpos
        end = data.qpos.copy()
        end[moved_qpos] = qpos[i][: moved_qpos.stop - moved_qpos.start]
        mujoco.mj_differentiatePos(model, velocities[i], step_s, starts[i], end)
    mine = np.zeros(model.nv, dtype=bool)
    mine[moved_qvel] = True
    velocities[:, ~mine] = 0.0
    return moved_qpos, moved_qvel, starts, velocities


def move_puppet(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    paths: PuppetPaths,
    i: int,
    elapsed_s: float,
) -> None:
    """Put environment i's puppet where its path is `elapsed_s` into the step."""
    qpos_slice, qvel_slice, starts, velocities = paths
    here = starts[i].copy()
    mujoco.mj_integratePos(model, here, velocities[i], elapsed_s)
    data.qpos[qpos_slice] = here[qpos_slice]
    data.qvel[qvel_slice] = velocities[i, qvel_slice]
