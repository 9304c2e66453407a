"""How the arena's batch is stepped: one interface (`Stepping`), a module per backend, chosen once
by `EnvConfig.stepping` through `BACKENDS`.

Batched stepping, three ways (`EnvConfig.stepping`), measured by `benchmarks/physics_speed.py`:
- "rollout" (default, `rollout`): `mujoco.rollout.Rollout`, MuJoCo's own thread pool, contacts
  from the arena's contact sensors; it agrees with "threads" to the solver's tolerance.
- "threads" (`threads`): a pool of `threads` workers steps contiguous chunks of the N MjData
  with `mj_step`, reading the contacts from `MjData.contact` between substeps; bit-identical to
  stepping the environments one by one, and the only one that takes a puppet.
- "warp" (`warp`): MuJoCo Warp steps all N environments as the worlds of one batch, on the GPU
  where there is one; contacts come from the contact sensors as with "rollout". The state stays
  on the device, where the PD targets, the kinematics, damage, observations and episode starts
  are computed too; a step's observations, damage and bodies are torch tensors there
  (`models.arena.env.StepResult`), and the MjData are brought from the device only when read
  (`ArenaEnv.datas`).
Measured by `benchmarks/physics_speed.py` on 2 cores, N = 64, 60 Hz x 2: the whole step runs
at about 7,500 environment steps/s with "rollout" and 5,800 with "threads" (raw physics alone:
14-15k with either): "rollout" steps its environments back to back in C, while "threads" reads
the contacts from Python between substeps. The observations are gathered once per environment
(`world_frames`, a few array copies) and computed for all environments and both agents in one
vectorised pass: 1.1 ms per step for 64 environments, 15 % of the raw physics (computing
`body_state` per environment and agent cost 72 %).

Every backend works on the arena's `HostWorlds` (`host`: the N MjData and the host's copies of
the bodies); the CPU ones step those MjData themselves, Warp keeps them as a copy of its worlds.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from models.arena.config import EnvConfig
from models.arena.puppet import Puppet, PuppetPaths
from models.arena.stepping.host import HostWorlds
from models.arena.stepping.rollout import RolloutStepping
from models.arena.stepping.threads import ThreadsStepping
from models.arena.stepping.warp import WarpStepping

if TYPE_CHECKING:  # torch only where Warp's arrays are (annotations)
    import torch

    Array = np.ndarray | torch.Tensor


class Stepping(Protocol):
    """What a physics backend does for the arena (`models.arena.env.ArenaEnv`), which holds one.

    Arrays "where the physics runs" are NumPy arrays on the host, or with "warp" torch tensors
    on its device.
    """

    def physics_array(self, actions: Array) -> Array:
        """``actions`` (any shape, NumPy or torch) in float64 where the physics runs."""
        ...

    def advance(
        self,
        ctrl: Array,
        *,
        contacts: bool,
        paths: PuppetPaths | None = None,
        pushes: np.ndarray | None = None,
    ) -> tuple[Array, Array]:
        """Hold ``ctrl`` (N, nu), and ``pushes`` (N, nbody, 6: xfrc_applied, on the host) where
        given, for `EnvConfig.substeps` physics steps in every environment; no applied force is
        left on afterwards.
        With ``contacts``, also bring the kinematics and `measured` to the new state and return
        each agent's damage (N, 2) and floor touches (N, 2, bool); without, only step (the
        damage and touches are zeros). ``paths`` (`puppet_paths`) moves a puppet along its path
        before every substep."""
        ...

    def measured(self) -> tuple[Array, Array, Array]:
        """What the observations and the fall rule read, as the last move left it, where the
        physics runs: (N, nbody, 21) `world_frames`, (N, 2) head heights, (N,) stability."""
        ...

    def start(
        self,
        ids: np.ndarray,
        qpos: np.ndarray,
        qvel: np.ndarray,
        ground: Sequence[np.ndarray] | None,
    ) -> Array:
        """Environments ``ids`` reset and started with both agents at ``qpos`` (n, 2, 35) moving
        at ``qvel`` (n, 2, 34), with ``ground`` (each agent's geoms) each fighter grounded
        (`models.arena.starts.start_world`); their (n, nbody, 21) frames."""
        ...

    def root_quats(self) -> Array:
        """(N, 2, 4) each agent's root quaternion, where the physics runs."""
        ...

    def puppet_paths(self, puppet: Puppet) -> PuppetPaths:
        """The puppet's paths for the next `advance` (`models.arena.puppet.puppet_paths`), or
        ValueError(`models.arena.puppet.NEEDS_THREADS`) where the backend takes none."""
        ...

    def sync(self) -> None:
        """The host's copies (the MjData, `HostWorlds`' bodies) brought to the worlds' state."""
        ...

    def written(self, ids: np.ndarray | slice) -> None:
        """The host's copies of environments ``ids`` were set (after a `sync`, or all of them
        as a whole): they are the worlds' state from now on, taken before the next move."""
        ...

    def close(self) -> None:
        """End what the backend started (threads); safe to call twice."""
        ...


@dataclass(frozen=True)
class Backend:
    """One way of stepping: whether its arena needs contact sensors, and how to make it on the
    arena's worlds, its settings and the torch device's name."""

    contact_sensors: bool
    make: Callable[[HostWorlds, EnvConfig, str], Stepping]


BACKENDS: Mapping[str, Backend] = {
    "rollout": Backend(contact_sensors=True, make=RolloutStepping),
    "threads": Backend(contact_sensors=False, make=ThreadsStepping),
    "warp": Backend(contact_sensors=True, make=WarpStepping),
}
