"""The arena's worlds on the host: the N MjData and the copies of what the observations and the
fall rule read (`HostWorlds`), and what the two steppings on the CPU ("threads", "rollout")
share (`OnHost`): there the MjData are the worlds, with nothing to bring down or send up.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import mujoco
import numpy as np
from array_api_compat import is_torch_array

from models.arena.config import EnvConfig
from models.arena.mjcf import NUM_AGENTS, ArenaIndex
from models.arena.puppet import NEEDS_THREADS, Puppet, PuppetPaths
from models.arena.starts import start_world
from models.humanoid.kinematics import ROOT_QUAT
from models.humanoid.observations import FRAME_WIDTH, world_frames

if TYPE_CHECKING:  # torch only where Warp's arrays are (annotations)
    import torch


def to_host(array: np.ndarray | torch.Tensor) -> np.ndarray:
    """A float64 NumPy array of an arena's array (with "warp", a torch tensor on its device)."""
    host = array.cpu().numpy() if is_torch_array(array) else array
    return np.asarray(host, dtype=np.float64)


def refresh(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """Kinematics and body velocities at the current qpos and qvel (what
    `models.humanoid.compiled.body_state` reads), as `body_states` computes them for the
    demonstrations."""
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    mujoco.mj_comVel(model, data)


class HostWorlds:
    """N worlds of one arena model on the host.

    Attributes:
        model: the compiled arena.
        index: its ArenaIndex.
        datas: the N MjData.
        frames: (N, nbody, 21) each world's `world_frames`, as `gather` last read them.
        head_z: (N, 2) each agent's head sphere's centre height, likewise.
        stable: (N,) whether each world's positions and velocities were finite and within
            mjMAXVAL, likewise.
    """

    def __init__(self, model: mujoco.MjModel, index: ArenaIndex, num_envs: int):
        self.model = model
        self.index = index
        self.datas = [mujoco.MjData(model) for _ in range(num_envs)]
        self.frames = np.empty((num_envs, model.nbody, FRAME_WIDTH))
        self.head_z = np.empty((num_envs, NUM_AGENTS))
        self.stable = np.ones(num_envs, dtype=bool)
        for i in range(num_envs):
            self.gather(i)

    def gather(self, i: int, *, check: bool = True) -> None:
        """Refresh environment i's kinematics and copy what the observations and the fall rule
        read into row i of `frames` and `head_z`; with ``check``, row i of `stable` too (a
        caller that has every world's state in one array checks them at once, `stable_states`)."""
        data = self.datas[i]
        refresh(self.model, data)
        world_frames(self.model, data, self.frames[i])
        self.head_z[i] = data.geom_xpos[self.index.head_geoms, 2]
        if check:
            self.stable[i] = bool(stable_states(data.qpos) and stable_states(data.qvel))


def stable_states(values: np.ndarray) -> np.ndarray:
    """(...) whether every position and velocity in ``values`` (..., k) is finite and within
    mjMAXVAL: MuJoCo's own test (mj_checkPos, mj_checkVel). NaN fails the comparison."""
    return np.all(np.abs(values) < mujoco.mjMAXVAL, axis=-1)


class OnHost:
    """What "threads" and "rollout" share (`models.arena.stepping.Stepping`): the MjData are the
    worlds, so there is nothing to sync; a puppet is refused unless a stepping takes one."""

    def __init__(self, worlds: HostWorlds, config: EnvConfig):
        self.worlds = worlds
        self.model = worlds.model
        self.config = config

    def physics_array(self, actions: np.ndarray | torch.Tensor) -> np.ndarray:
        return to_host(actions)

    def measured(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.worlds.frames, self.worlds.head_z, self.worlds.stable

    def root_quats(self) -> np.ndarray:
        agents = self.worlds.index.agents
        return np.array([[d.qpos[a.qpos][ROOT_QUAT] for a in agents] for d in self.worlds.datas])

    def start(
        self,
        ids: np.ndarray,
        qpos: np.ndarray,
        qvel: np.ndarray,
        ground: Sequence[np.ndarray] | None,
    ) -> np.ndarray:
        worlds = self.worlds
        for k, i in enumerate(ids):
            start_world(self.model, worlds.index.agents, worlds.datas[i], qpos[k], qvel[k], ground)
            worlds.gather(i)
        return worlds.frames[ids]

    def puppet_paths(self, puppet: Puppet) -> PuppetPaths:
        raise ValueError(NEEDS_THREADS)

    def sync(self) -> None:
        pass

    def written(self, ids: np.ndarray | slice) -> None:
        pass

    def close(self) -> None:
        pass
