"""Stepping "warp": the arena's physics on MuJoCo Warp, every environment a world of one batched
simulation.

`EnvConfig.stepping = "warp"`. MuJoCo Warp (`mujoco-warp`, Google DeepMind and NVIDIA) reads the
same MJCF as MuJoCo and steps thousands of worlds in one batch on an NVIDIA GPU; it also runs on
the CPU, slowly, which is what the tests and this 2-core machine use. Its arrays are float32,
MuJoCo's float64: trajectories agree to float32's precision for a while, then part as any two
floating-point schedules of a contact-rich simulation do (measured in tests/test_warp.py).

What runs where: the worlds' state lives on the device, and the device is where a policy step
happens: the actions become PD targets there (`models.humanoid.kinematics`, which takes torch
tensors), the physics substeps, the contact sensors are summed into damage and floor touches,
the bodies' kinematics and the observations (`models.humanoid.observations`, the dataset's own
function, on torch views of Warp's arrays) are computed, and the arena returns them there
(`StepResult`). Only the flags the host decides resets by come down each step (falls,
instability: a few bytes per world). An episode start is chosen on the host (which reference
frame, whether standing: the arena's generator, as with MuJoCo's stepping) and made on the
device: the poses go up and are grounded, and their kinematics and observations computed, there
(`ArenaEnv.reset`). The arena's MjData, and its host copies of the bodies, are brought down only
when read (`ArenaEnv.datas`, `ArenaEnv.body_states`: a checkpoint, the tracker's rewards, which
are computed on the host), and what is set on the host (`ArenaEnv.place`, a checkpoint's state)
goes up before the device moves again.

Contacts come from the arena's contact sensors (`arena_mjcf(contact_sensors=True)`), as with
"rollout". MuJoCo's automatic reset is not in Warp; Warp never resets a world on its own, so an
unstable world is caught by the arena's own finiteness test as before.

`WarpPhysics` is the device layer (the worlds on Warp's arrays, as torch views); `WarpStepping`
is the arena's stepping on it, which keeps the host's copies (`HostWorlds`) in step with the
device: what the host set since the device last moved goes up before it moves again, and the
MjData and the host's bodies come down only when read (`sync`).
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Sequence

import mujoco
import numpy as np
from array_api_compat import array_namespace

from models.arena.config import EnvConfig
from models.arena.contacts import sensor_contacts
from models.arena.mjcf import NUM_AGENTS
from models.arena.puppet import NEEDS_THREADS, Puppet, PuppetPaths
from models.arena.starts import bottoms
from models.arena.stepping.host import HostWorlds
from models.humanoid.kinematics import ROOT_QUAT

# The state that decides the next step, as `mujoco.mj_step` reads it (mjSTATE_INTEGRATION less
# what the arena never sets: applied forces, mocap, equality switches).
_STATE_FIELDS = ("qpos", "qvel", "act", "qacc_warmstart", "ctrl")
# Room per world on the device: contacts (of the fighters with each other and the floor) and
# the solver's constraint rows (4 per contact with the pyramidal cone and condim 3, plus joint
# limits). A world that needs more raises WarpOverflow instead of losing contacts.
CONTACTS_PER_WORLD = 96
ROWS_PER_WORLD = 1024


class WarpOverflow(RuntimeError):
    """The device ran out of room for contacts or constraint rows in some world: its physics
    would silently have gone wrong."""


@functools.cache
def _warp():
    """warp and mujoco_warp, imported (and Warp initialised quietly) on first use: importing
    them costs seconds, and Warp's banner would otherwise land in the CLI's JSON output."""
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING  # no banner, no line per kernel module loaded
    import mujoco_warp as mjw

    wp.init()
    return wp, mjw


def warp_device(name: str) -> str:
    """Warp's name for torch device ``name`` ('cpu', 'cuda', 'cuda:1')."""
    if name.startswith("cuda"):
        return name if ":" in name else "cuda:0"
    return "cpu"


class WarpPhysics:
    """``num_envs`` worlds of ``model`` on the Warp device ``device``."""

    def __init__(self, model: mujoco.MjModel, num_envs: int, device: str = "cpu"):
        wp, mjw = _warp()
        self.device = device
        host = copy.copy(model)
        # Not in Warp (it never resets a world by itself, the same behaviour).
        host.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
        with wp.ScopedDevice(device):
            self._model = mjw.put_model(host)
            self._data = mjw.put_data(
                host,
                mujoco.MjData(host),
                nworld=num_envs,
                nconmax=CONTACTS_PER_WORLD,
                njmax=ROWS_PER_WORLD,
            )
        self._fatal = int(
            mjw.OverflowType.NEFC
            | mjw.OverflowType.NJMAX_NNZ
            | mjw.OverflowType.BROADPHASE
            | mjw.OverflowType.NARROWPHASE
            | mjw.OverflowType.CCD
        )
        self._names = mjw.OverflowType
        self._root_ids = model.body_rootid.tolist()

    @property
    def torch_device(self):
        """The torch device of Warp's arrays."""
        wp, _ = _warp()
        return wp.device_to_torch(self.device)

    def view(self, name: str):
        """A torch view (no copy) of Warp's array ``name`` (qpos, geom_xpos, ...), (N, ...)."""
        wp, _ = _warp()
        return wp.to_torch(getattr(self._data, name))

    def upload(self, ids: np.ndarray, datas: list[mujoco.MjData]) -> None:
        """Set worlds ``ids`` to the state of their MjData (``datas``, one per world): what
        decides the next step (`_STATE_FIELDS` and the time); their kinematics follow at the
        next `refresh` or `advance`."""
        import torch

        rows = torch.as_tensor(ids, device=self.torch_device)
        for name in _STATE_FIELDS:
            values = np.stack([getattr(datas[i], name) for i in ids])
            self.view(name)[rows] = torch.as_tensor(values).to(rows.device).float()
        times = torch.as_tensor([datas[i].time for i in ids])
        self.view("time")[rows] = times.to(rows.device).float()

    def start(self, ids, qpos, qvel) -> None:
        """Worlds ``ids`` (a torch index on the device) reset, as `mujoco.mj_resetData` does,
        then at ``qpos`` (n, nq) and ``qvel`` (n, nv) (tensors on the device); their kinematics
        follow at the next `refresh` or `advance`."""
        for name in _STATE_FIELDS:
            self.view(name)[ids] = 0.0
        self.view("time")[ids] = 0.0
        self.view("qpos")[ids] = qpos.float()
        self.view("qvel")[ids] = qvel.float()

    def refresh(self, *, velocities: bool = True) -> None:
        """Every world's kinematics at its positions (and, with ``velocities``, the bodies'
        velocities too), as `models.arena.stepping.host.refresh` computes them on the CPU."""
        wp, mjw = _warp()
        with wp.ScopedDevice(self.device):
            mjw.kinematics(self._model, self._data)
            if velocities:
                mjw.com_pos(self._model, self._data)
                mjw.com_vel(self._model, self._data)

    def advance(self, ctrl, substeps: int, pushes: np.ndarray | None = None):
        """Step every world ``substeps`` times holding ``ctrl`` (N, nu: a NumPy array, or a
        torch tensor on the device) and ``pushes`` (N, nbody, 6: xfrc_applied) where given, then
        bring its kinematics to the new state; the sensor values after each substep, (N,
        substeps, nsensordata), as `mujoco.rollout` returns them, a torch tensor on the device.
        WarpOverflow, in one line, if a world ran out of room for its contacts or constraints."""
        import torch

        wp, mjw = _warp()
        d = self._data
        self.view("ctrl").copy_(torch.as_tensor(ctrl, device=self.torch_device))
        if pushes is not None:
            self.view("xfrc_applied").copy_(torch.as_tensor(pushes, device=self.torch_device))
        d.overflow.zero_()
        sensors = []
        with wp.ScopedDevice(self.device):
            for _ in range(substeps):
                mjw.step(self._model, d)
                sensors.append(wp.to_torch(d.sensordata).clone())
        if pushes is not None:
            self.view("xfrc_applied").zero_()
        # What `mujoco.mj_step` leaves a substep behind, brought to the new state.
        self.refresh()
        overflow = d.overflow.numpy() & self._fatal
        if overflow.any():
            world = int(np.flatnonzero(overflow)[0])
            raise WarpOverflow(
                f"MuJoCo Warp ran out of room in world {world} "
                f"({self._names(int(overflow[world])).name}): raise CONTACTS_PER_WORLD or "
                f"ROWS_PER_WORLD in models/arena/stepping/warp.py"
            )
        return torch.stack(sensors, dim=1)

    def download(self, datas: list[mujoco.MjData]) -> None:
        """Write every world's state into its MjData (its kinematics are left as they were)."""
        d = self._data
        for name in _STATE_FIELDS:
            values = getattr(d, name).numpy()
            for i, data in enumerate(datas):
                getattr(data, name)[:] = values[i]
        times = d.time.numpy()
        for i, data in enumerate(datas):
            data.time = float(times[i])

    def stable(self):
        """(N,) torch bools on the device: whether each world's positions and velocities are
        finite and within mjMAXVAL (MuJoCo's mj_checkPos and mj_checkVel)."""
        import torch

        state = torch.cat([self.view("qpos"), self.view("qvel")], dim=1)
        return (state.abs() < mujoco.mjMAXVAL).all(dim=1)

    def frames(self):
        """(N, nbody, 21) torch tensor on the device of every world's bodies after the last
        `refresh`, as `models.humanoid.observations.world_frames` lays them out (xpos, xmat,
        cvel, the subtree_com of each body's tree root), built from Warp's arrays as torch
        views (no copy to the host)."""
        import torch

        n = self._data.xpos.shape[0]
        return torch.cat(
            [
                self.view("xpos"),
                self.view("xmat").reshape(n, -1, 9),
                self.view("cvel"),
                self.view("subtree_com")[:, self._root_ids],
            ],
            dim=-1,
        )


class WarpStepping:
    """The arena's worlds on MuJoCo Warp (`models.arena.stepping.Stepping`; module docstring).

    Attributes:
        physics: the worlds on the device.
        worlds: the host's copies: the MjData, and the bodies the observations read.
    """

    def __init__(self, worlds: HostWorlds, config: EnvConfig, device: str = "cpu"):
        self.worlds = worlds
        self.model = worlds.model
        self.config = config
        # The device holds the truth and the host a copy: the environments set on the host
        # since the device last moved (to go up before it moves again), and whether the MjData
        # and the host's frames, head heights and stability are behind it.
        self._dirty = np.ones(config.num_envs, dtype=bool)
        self._stale = False
        self.physics = WarpPhysics(self.model, config.num_envs, warp_device(device))
        self._measured: tuple | None = None

    def close(self) -> None:
        pass

    def sync(self) -> None:
        """The worlds' state into the MjData, and what the observations and the fall rule read
        into the host's frames, head heights and stability."""
        if not self._stale:
            return
        worlds = self.worlds
        self.physics.download(worlds.datas)
        frames, head_z, stable = self.measured()
        worlds.frames[:] = frames.cpu().numpy()
        worlds.head_z[:] = head_z.cpu().numpy()
        worlds.stable[:] = stable.cpu().numpy()
        self._stale = False

    def written(self, ids: np.ndarray | slice) -> None:
        self._dirty[ids] = True
        self._stale = False

    def _upload_dirty(self) -> None:
        """The environments set on the host since the device last moved go up before it moves
        again (a step or a start, which compute their kinematics there)."""
        if self._dirty.any():
            self.physics.upload(np.flatnonzero(self._dirty), self.worlds.datas)
            self._dirty[:] = False

    def measured(self) -> tuple:
        """(N, nbody, 21) body frames, (N, 2) head heights and (N,) stability of every world as
        the device last left them, torch tensors there (read once per move)."""
        if self._measured is None:
            head_z = self.physics.view("geom_xpos")[:, self.worlds.index.head_geoms.tolist(), 2]
            self._measured = self.physics.frames(), head_z, self.physics.stable()
        return self._measured

    def physics_array(self, actions):
        import torch

        return torch.as_tensor(actions).to(self.physics.torch_device, torch.float64)

    def root_quats(self):
        self._upload_dirty()
        qpos = self.physics.view("qpos").double()
        rows = [qpos[:, a.qpos][:, ROOT_QUAT] for a in self.worlds.index.agents]
        return array_namespace(qpos).stack(rows, axis=1)

    def puppet_paths(self, puppet: Puppet) -> PuppetPaths:
        raise ValueError(NEEDS_THREADS)

    def start(
        self,
        ids: np.ndarray,
        qpos: np.ndarray,
        qvel: np.ndarray,
        ground: Sequence[np.ndarray] | None,
    ):
        """The starts go up as they are and are grounded there (``ground``: each agent's geoms,
        or None); the started worlds' frames (n, nbody, 21), on the device."""
        warp, model, agents = self.physics, self.model, self.worlds.index.agents
        self._upload_dirty()
        full_q = np.tile(model.qpos0, (len(ids), 1))
        full_v = np.zeros((len(ids), model.nv))
        for a, agent in enumerate(agents):
            full_q[:, agent.qpos] = qpos[:, a]
            full_v[:, agent.qvel] = qvel[:, a]
        import torch

        rows = torch.as_tensor(ids, device=warp.torch_device)
        warp.start(rows, *(torch.as_tensor(x, device=rows.device) for x in (full_q, full_v)))
        if ground:
            warp.refresh(velocities=False)
            xpos, xmat = warp.view("geom_xpos")[rows], warp.view("geom_xmat")[rows]
            lows = [
                bottoms(model, geoms, xpos[:, geoms.tolist()], xmat[:, geoms.tolist()])
                for geoms in ground
            ]
            for agent, low in zip(agents, lows, strict=True):
                warp.view("qpos")[rows, agent.qpos_start + 2] -= low.amin(dim=1)
        warp.refresh()
        self._measured, self._stale = None, True
        return self.measured()[0][rows]

    def advance(
        self,
        ctrl,
        *,
        contacts: bool,
        paths: PuppetPaths | None = None,
        pushes: np.ndarray | None = None,
    ):
        self._upload_dirty()
        sensordata = self.physics.advance(ctrl, self.config.substeps, pushes)
        self._measured, self._stale = None, True
        if not contacts:
            n = self.config.num_envs
            return np.zeros((n, NUM_AGENTS)), np.zeros((n, NUM_AGENTS), dtype=bool)
        sensors = self.worlds.index.sensors
        assert sensors is not None
        return sensor_contacts(sensordata, sensors)
