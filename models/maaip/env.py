"""The two-fighter training environment: N arenas of one MuJoCo model, stepped in a batch.

MAAIP (Younes et al., PACMCGIT 6(3), 2023, §4.2, §5): two physics-based boxers, each
driven by a policy at 30 Hz whose 28 actions are PD targets (exponential maps for the 3-DoF
joints, angles for elbows and knees); the physics runs at 60 Hz with 2 substeps in the paper
(`EnvConfig.substeps` = 2, timestep 1 / 60 s), or here at 120 Hz with 4.

One environment step (`ArenaEnv.step`):
1. actions (N, 2, 28) -> hinge targets (`action_to_joint_targets`), clipped to each
   actuator's ctrlrange, held for `substeps` calls of `mj_step`;
2. after each substep, the contacts give each agent's damage and floor touches;
3. after the last, the kinematics are brought to the new state (`mj_step` leaves them one
   substep behind) and each agent observes itself and its opponent with
   `models.humanoid.observations.observation` (274 numbers), the function the dataset stage
   uses for the demonstrations.

Damage (MAAIP §5.3): an agent's damage in a step is the sum, over the step's substeps and
over the contacts between one of its head, torso or pelvis geoms and any geom of the other
agent, of the contact's normal force in newtons (`mujoco.mj_contactForce`). A contact of two
targets (head on head) damages both. Gloves and limbs take no damage.

Falls (early termination): an agent has fallen when, in any substep, one of its geoms other
than its feet and shins touches the floor (boxing's knockdown rule: any part of the body but
the soles on the canvas, a glove included; the shins are spared because their capsules end
round the ankle, 2 cm above the sole, and graze the floor when a foot rolls over, while a knee
on the canvas touches with the thicker thigh capsule first), or when its head sphere's centre
is below `EnvConfig.fall_height_m` after the step (a knockdown caught against the ropes or
the opponent). A fall of either agent ends the episode for both and is terminal; reaching
`episode_s` is a time-out, which is not terminal (the trainer bootstraps from the value of
the last observation). Episodes do not restart on their own: the trainer calls `reset` for
the environments whose `done` is set.

Instability: MuJoCo's automatic reset is off in the arena (mjDSBL_AUTORESET). An environment
whose positions or velocities are no longer finite or exceed mjMAXVAL after a step is
`unstable`: its episode ends (terminal) with zeros for observation and damage, and the
trainer resets it like any other finished environment and counts it.

Batched stepping, three ways (`EnvConfig.stepping`), measured by `benchmarks/physics_speed.py`:
- "rollout" (default): `mujoco.rollout.Rollout`, MuJoCo's own thread pool. It takes and
  returns states (mjSTATE_FULLPHYSICS) and sensor values, not MjData: contacts come from
  contact sensors the arena gets for it (`arena_mjcf(contact_sensors=True)`; they report the
  normal forces `mj_contactForce` gives, in up to 8 contacts per target body and substep),
  and the final states are copied back into the MjData, whose kinematics are then refreshed
  for the observations. The solver's warm start (qacc_warmstart) is not part of the
  returned state, so each call starts it cold; the trajectories agree with "threads" to the
  solver's tolerance (1e-13 m over 6 steps in the tests), not bit for bit.
- "threads": a pool of `threads` workers steps contiguous chunks of the N MjData with
  `mj_step`, which releases the GIL; after every substep a worker reads the contacts from
  `MjData.contact` (`mj_contactForce`), and after the chunk it refreshes the kinematics and
  reads the body states. Bit-identical to stepping the environments one by one.
- "warp": MuJoCo Warp steps all N environments as the worlds of one batch, on the GPU where
  there is one (`models.maaip.warp_physics`); contacts come from the contact sensors as with
  "rollout". The state stays on the device, where the PD targets, the kinematics, damage,
  observations and episode starts are computed too; a step's observations, damage and bodies
  are torch tensors there (`StepResult`), and the MjData are brought from the device only when
  read (`ArenaEnv.datas`).
Measured by `benchmarks/physics_speed.py` on 2 cores, N = 64, 60 Hz x 2: the whole step runs
at about 7,500 environment steps/s with "rollout" and 5,800 with "threads" (raw physics alone:
14-15k with either): "rollout" steps its environments back to back in C, while "threads" reads
the contacts from Python between substeps. The observations are gathered once per environment
(`world_frames`, a few array copies) and computed for all environments and both agents in one
vectorised pass: 1.1 ms per step for 64 environments, 15 % of the raw physics (computing
`body_state` per environment and agent cost 72 %).

A puppet (`Puppet`, for live sparring): one agent moved through given poses instead of by its
actuators. Before every substep its qpos and qvel are set on the path from where it is to the
step's pose at constant velocity (`mj_differentiatePos`, `mj_integratePos`), and after the last
it is exactly at that pose; the solver still computes its contacts, so the other fighter is
pushed and struck by it, and damage and falls are read as for any agent. A puppet by the root
only has its pelvis moved so, and its limbs driven by its actions as usual. Only "threads"
stepping takes one ("rollout" steps in C without a hook between substeps).

Shape letters: N environments, M reference frames, 2 agents.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING

import mujoco
import mujoco.rollout
import numpy as np
from array_api_compat import array_namespace, device, is_torch_array
from scipy.spatial.transform import Rotation

from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import (
    NQ,
    NUM_ACTUATED,
    NV,
    ROOT_POS,
    ROOT_QUAT,
    action_to_joint_targets,
    heading_yaw,
)
from models.humanoid.observations import (
    FRAME_WIDTH,
    SELF_DIM,
    BodyState,
    body_state_from_frames,
    observation,
    world_frames,
)
from models.maaip.arena import (
    DAMAGE_SENSOR_SLOTS,
    NUM_AGENTS,
    ArenaIndex,
    SensorLayout,
    arena_index,
    arena_mjcf,
)
from models.maaip.config import EnvConfig
from models.maaip.demonstrations import ReferenceMotions

if TYPE_CHECKING:  # torch only where Warp's observations are (annotations)
    import torch

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION


@dataclass(frozen=True, eq=False)
class StepResult:
    """What one `ArenaEnv.step` returns.

    With stepping "warp", `observation`, `self_observation`, `damage` and `body` are torch
    tensors (float32) on Warp's device, where they were computed; the flags, which the host
    decides resets by, are NumPy arrays with every stepping.

    Attributes:
        observation: (N, 2, 274) each agent's o_{t+1} = [o^self, o^opp] (MAAIP §4.2).
        self_observation: (N, 2, 223) o^self_{t+1}, the first 223 numbers of `observation`
            (the motion discriminator's half of a transition).
        terminated: (N,) a fighter fell: terminal, no bootstrapping.
        truncated: (N,) the episode reached `episode_s` without a fall: bootstrap.
        fell: (N, 2) which agents fell this step.
        damage: (N, 2) newtons each agent received this step (module docstring).
        unstable: (N,) the simulation blew up (a position or velocity not finite or beyond
            MuJoCo's mjMAXVAL): terminal, the observation and damage are zeros; reset it.
        body: (N, 2) both agents' body states after the step, which the observations are
            computed from (not finite where unstable).
    """

    observation: np.ndarray | torch.Tensor
    self_observation: np.ndarray | torch.Tensor
    terminated: np.ndarray
    truncated: np.ndarray
    fell: np.ndarray
    damage: np.ndarray | torch.Tensor
    unstable: np.ndarray
    body: BodyState

    @property
    def done(self) -> np.ndarray:
        """(N,) the environments the trainer must reset."""
        return self.terminated | self.truncated


# --------------------------------------------------------------------------
# Pure helpers
# --------------------------------------------------------------------------


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


def joint_targets(actions: np.ndarray, ctrlrange: np.ndarray) -> np.ndarray:
    """PD targets of both agents from the paper's actions, clipped to the actuators' ranges.

    Args:
        actions: (N, 2, 28) MAAIP §4.2 actions (exp maps and angles, JOINT_LAYOUT order).
        ctrlrange: (2, 28, 2) each agent's actuator ranges (low, high) in radians.

    Returns:
        (N, 2, 28) hinge targets in radians (a torch tensor where ``actions`` is one, on its
        device).
    """
    targets = action_to_joint_targets(actions)
    xp = array_namespace(targets)
    limits = xp.asarray(ctrlrange, dtype=targets.dtype, device=device(targets))
    return xp.clip(targets, limits[..., 0], limits[..., 1])


def geom_bottoms(model: mujoco.MjModel, data: mujoco.MjData, geoms: np.ndarray) -> np.ndarray:
    """The lowest world z of each geom (spheres, capsules and boxes), from current kinematics.

    Args:
        model, data: a model and its data after at least `mj_kinematics`.
        geoms: (G,) geom ids.

    Returns:
        (G,) heights in metres.
    """
    xmat = data.geom_xmat[geoms].reshape(-1, 3, 3)
    return bottoms(model, geoms, data.geom_xpos[geoms], xmat)


def bottoms(model: mujoco.MjModel, geoms: np.ndarray, xpos: np.ndarray, xmat: np.ndarray):
    """`geom_bottoms` from the geoms' world positions ``xpos`` (..., G, 3) and orientations
    ``xmat`` (..., G, 3, 3), of any batch of worlds: NumPy arrays, or torch tensors (Warp's
    worlds on their device), which give tensors there."""
    kinds = model.geom_type[geoms]
    known = (mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_BOX)
    if not np.isin(kinds, known).all():
        bad = [int(g) for g in np.asarray(geoms)[~np.isin(kinds, known)]]
        raise ValueError(f"geom_bottoms handles spheres, capsules and boxes; geoms {bad} are not")
    xp = array_namespace(xpos)
    size = xp.asarray(model.geom_size[geoms], dtype=xpos.dtype, device=device(xpos))
    centre_z = xpos[..., 2]
    zrow = xmat[..., 2, :]  # world z of each local axis
    sphere = centre_z - size[:, 0]
    capsule = centre_z - xp.abs(zrow[..., 2]) * size[:, 1] - size[:, 0]
    box = centre_z - xp.sum(xp.abs(zrow) * size, axis=-1)
    is_sphere = xp.asarray(kinds == mujoco.mjtGeom.mjGEOM_SPHERE, device=device(xpos))
    is_capsule = xp.asarray(kinds == mujoco.mjtGeom.mjGEOM_CAPSULE, device=device(xpos))
    return xp.where(is_sphere, sphere, xp.where(is_capsule, capsule, box))


def start_velocities(qvel: np.ndarray, mode: str, limit: float) -> np.ndarray:
    """Velocities (n, 34) to start episodes with, from the reference's (`EnvConfig.reset_velocity`):
    zeros, the reference's clipped to +-`limit` per coordinate, or the reference's as they are."""
    if mode == "zero":
        return np.zeros_like(qvel)
    if mode == "clip":
        return np.clip(qvel, -limit, limit)
    return qvel.copy()


def standing_like(qpos: np.ndarray, hinges: np.ndarray | None = None) -> np.ndarray:
    """Upright with ``hinges`` (28,) (None: the rest pose, every hinge at 0) where each of
    ``qpos`` (n, 35) stands, facing its heading; the height is left to the caller's grounding."""
    out = np.zeros_like(qpos)
    if hinges is not None:
        out[:, 7:] = hinges
    out[:, ROOT_POS] = qpos[:, ROOT_POS]
    yaw = heading_yaw(qpos[:, ROOT_QUAT])
    out[:, ROOT_QUAT] = Rotation.from_euler("z", yaw[:, None]).as_quat(scalar_first=True)
    return out


def centred_pair(qpos0: np.ndarray, qpos1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both fighters shifted horizontally so that the midpoint of their pelvises is the origin.

    Args:
        qpos0, qpos1: (..., 35) the two fighters' qpos in one world frame.

    Returns:
        The shifted copies.
    """
    shift = (qpos0[..., :2] + qpos1[..., :2]) / 2
    out0, out1 = qpos0.copy(), qpos1.copy()
    out0[..., :2] -= shift
    out1[..., :2] -= shift
    return out0, out1


@dataclass(frozen=True, eq=False)
class _ContactTables:
    """Per-pair lookups for reading contacts fast: pair_kind[g1, g2] says what a contact
    between geoms g1 and g2 means (0: nothing to record)."""

    # (ngeom, ngeom) int: bit a (1 << a) if the pair damages agent a, bit 2 + a if agent a
    # touches the floor with a geom other than its feet and shins.
    pair_kind: np.ndarray


def _contact_tables(model: mujoco.MjModel, index: ArenaIndex) -> _ContactTables:
    ngeom = model.ngeom
    kind = np.zeros((ngeom, ngeom), dtype=np.int64)
    target = np.full(ngeom, -1)
    for a in range(NUM_AGENTS):
        target[index.damage_geoms[a]] = a
    owner = index.agent_of_geom
    grounded = np.zeros(ngeom, dtype=bool)
    grounded[index.grounded_geoms.ravel()] = True
    for g1 in range(ngeom):
        for g2 in range(ngeom):
            bits = 0
            if owner[g1] >= 0 and owner[g2] >= 0 and owner[g1] != owner[g2]:
                for g, other in ((g1, g2), (g2, g1)):
                    if target[g] >= 0 and owner[other] == 1 - target[g]:
                        bits |= 1 << int(target[g])
            for floor, body in ((g1, g2), (g2, g1)):
                if floor == index.floor_geom and owner[body] >= 0 and not grounded[body]:
                    bits |= 1 << (2 + int(owner[body]))
            kind[g1, g2] = bits
    kind.setflags(write=False)
    return _ContactTables(kind)


def _read_contacts(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    tables: _ContactTables,
    damage: np.ndarray,
    floor: np.ndarray,
    force: np.ndarray,
) -> None:
    """Add this substep's damage (2,) and floor touches (2,) of one environment in place.

    `data` is right after `mj_step`: its contacts and constraint forces are those the step
    computed (at the state before its integration).
    """
    if data.ncon == 0:
        return
    geom = data.contact.geom
    kinds = tables.pair_kind[geom[:, 0], geom[:, 1]]
    for c in np.flatnonzero(kinds):
        bits = int(kinds[c])
        if bits & 3:
            mujoco.mj_contactForce(model, data, int(c), force)
            for a in range(NUM_AGENTS):
                if bits & (1 << a):
                    damage[a] += force[0]
        for a in range(NUM_AGENTS):
            if bits & (1 << (2 + a)):
                floor[a] = True


def _move_puppet(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    paths: tuple[slice, slice, np.ndarray, np.ndarray],
    i: int,
    elapsed_s: float,
) -> None:
    """Put environment i's puppet where its path is `elapsed_s` into the step."""
    qpos_slice, qvel_slice, starts, velocities = paths
    here = starts[i].copy()
    mujoco.mj_integratePos(model, here, velocities[i], elapsed_s)
    data.qpos[qpos_slice] = here[qpos_slice]
    data.qvel[qvel_slice] = velocities[i, qvel_slice]


def sensor_contacts(sensordata: np.ndarray, layout: SensorLayout) -> tuple[np.ndarray, np.ndarray]:
    """Damage and floor touches from the arena's contact sensors, summed over substeps.

    Args:
        sensordata: (N, S, nsensordata) sensor values after each of S substeps (`mujoco.rollout`;
            a NumPy array, or a torch tensor on Warp's device, which gives tensors back).
        layout: from `arena_index` of a model built with contact_sensors=True.

    Returns:
        (N, 2) damage in newtons and (N, 2) bool floor touches by a geom other than the
        feet and shins.
    """
    xp = array_namespace(sensordata)
    width = 4  # found, then the force in the contact frame (normal first)
    damage, floor = [], []
    for a in range(NUM_AGENTS):
        total = 0.0
        for start in layout.damage[a]:
            slots = sensordata[..., start : start + DAMAGE_SENSOR_SLOTS * width]
            slots = xp.reshape(slots, (*slots.shape[:-1], DAMAGE_SENSOR_SLOTS, width))
            found = xp.where(slots[..., 0] > 0, slots[..., 1], xp.zeros_like(slots[..., 1]))
            total = total + xp.sum(found, axis=(1, 2))
        grounded = xp.sum(sensordata[..., list(layout.grounded[a])], axis=-1)
        damage.append(total)
        floor.append(xp.any(sensordata[..., layout.floor[a]] - grounded > 0, axis=1))
    return xp.stack(damage, axis=1), xp.stack(floor, axis=1)


def to_host(array: np.ndarray | torch.Tensor) -> np.ndarray:
    """A float64 NumPy array of an arena's array (with "warp", a torch tensor on its device)."""
    host = array.cpu().numpy() if is_torch_array(array) else array
    return np.asarray(host, dtype=np.float64)


def _refresh(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """Kinematics and body velocities at the current qpos and qvel (what
    `models.humanoid.compiled.body_state` reads), as `body_states` computes them for the
    demonstrations."""
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    mujoco.mj_comVel(model, data)


def _observations(states: BodyState) -> np.ndarray:
    """(n, 2, 274): agent k observes itself and agent 1 - k (MAAIP §4.2)."""
    return observation(states, states[:, [1, 0]])


def _check_ids(env_ids: Sequence[int] | np.ndarray, count: int) -> np.ndarray:
    ids = np.asarray(env_ids)
    if ids.dtype == bool:
        if ids.shape != (count,):
            raise ValueError(f"env_ids as a mask must have shape ({count},), got {ids.shape}")
        return np.flatnonzero(ids)
    ids = ids.reshape(-1)
    if ids.size and (
        not np.issubdtype(ids.dtype, np.integer) or ids.min() < 0 or ids.max() >= count
    ):
        raise ValueError(f"env_ids must be integers in [0, {count}), got {env_ids!r}")
    if len(np.unique(ids)) != len(ids):
        raise ValueError(f"env_ids must not repeat an environment, got {env_ids!r}")
    return ids.astype(int)


# --------------------------------------------------------------------------
# The environment
# --------------------------------------------------------------------------


class ArenaEnv:
    """N two-fighter arenas of one model; see the module docstring.

    Use as a context manager (or call `close`) so that the worker threads end.

    Attributes:
        config: the EnvConfig.
        model: the compiled arena (timestep 1 / (policy_hz * substeps)).
        index: ArenaIndex of the model.
        datas: the N MjData. Between calls they hold each environment's state, and with the
            CPU steppings its kinematics too (with "warp" those are read on the device: use
            `body_states`).
        elapsed: (N,) policy steps since each environment's reset.
    """

    def __init__(
        self,
        config: EnvConfig,
        rng: np.random.Generator,
        bones: tuple[BoneLengths, BoneLengths] = (BoneLengths(), BoneLengths()),  # noqa: B008
        device: str = "cpu",
    ):
        if not isinstance(config, EnvConfig):
            raise TypeError(f"config must be an EnvConfig, got {type(config).__name__}")
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy Generator, got {type(rng).__name__}")
        self.config = config
        self.rng = rng
        rollout = config.stepping == "rollout"
        warp = config.stepping == "warp"
        xml = arena_mjcf(bones, timestep=config.timestep, contact_sensors=rollout or warp)
        self.model = mujoco.MjModel.from_xml_string(xml)
        # An unstable simulation is caught here (`StepResult.unstable`) rather than silently
        # restarted by MuJoCo at the model's rest state, which would read as a teleport.
        self.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
        self.index = arena_index(self.model)
        self._datas = [mujoco.MjData(self.model) for _ in range(config.num_envs)]
        self.elapsed = np.zeros(config.num_envs, dtype=int)
        self._ctrlrange = self.model.actuator_ctrlrange[self.index.actuators]  # (2, 28, 2)
        self._tables = _contact_tables(self.model, self.index)
        self._body_ids = np.stack([agent.body_ids for agent in self.index.agents])  # (2, 15)
        self._frames = np.empty((config.num_envs, self.model.nbody, FRAME_WIDTH))
        self._head_z = np.empty((config.num_envs, NUM_AGENTS))
        self._stable = np.ones(config.num_envs, dtype=bool)
        for i in range(config.num_envs):
            self._gather(i)
        self._chunks = [
            c for c in np.array_split(np.arange(config.num_envs), config.threads) if c.size
        ]
        threaded = config.stepping == "threads" and len(self._chunks) > 1
        self._pool = ThreadPoolExecutor(len(self._chunks)) if threaded else None
        self._rollout = None
        if rollout:
            # nthread=0 runs on the calling thread: the sequential case of the same code.
            threads = config.threads if config.threads > 1 else 0
            self._rollout = mujoco.rollout.Rollout(nthread=threads)
            self._scratch = [mujoco.MjData(self.model) for _ in range(max(threads, 1))]
            self._nstate = mujoco.mj_stateSize(self.model, _FULL)
        # With "warp" the device holds the truth and the host a copy: the environments set on
        # the host since the device last moved (to go up before it moves again), and whether
        # the MjData and `_frames`, `_head_z`, `_stable` are behind it.
        self._dirty = np.ones(config.num_envs, dtype=bool)
        self._stale = False
        self._warp = None
        if warp:
            from models.maaip.warp_physics import WarpPhysics, warp_device

            self._warp = WarpPhysics(self.model, config.num_envs, warp_device(device))
            self._measured: tuple | None = None

    def close(self) -> None:
        """End the worker threads."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        if self._rollout is not None:
            self._rollout.close()
            self._rollout = None

    def __enter__(self) -> ArenaEnv:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def num_envs(self) -> int:
        return self.config.num_envs

    @property
    def datas(self) -> list[mujoco.MjData]:
        """The N MjData, holding each environment's state. With "warp" they are brought from the
        device when read, and what is written into them goes up before the next step."""
        self._sync()
        if self._warp is not None:
            self._dirty[:] = True
        return self._datas

    def _sync(self) -> None:
        """With "warp": the worlds' state into the MjData, and what the observations and the
        fall rule read into `_frames`, `_head_z` and `_stable`."""
        if self._warp is None or not self._stale:
            return
        self._warp.download(self._datas)
        frames, head_z, stable = self._on_device()
        self._frames[:] = frames.cpu().numpy()
        self._head_z[:] = head_z.cpu().numpy()
        self._stable[:] = stable.cpu().numpy()
        self._stale = False

    def _upload_dirty(self) -> None:
        """With "warp": the environments set on the host since the device last moved go up
        before it moves again (a step or a start, which compute their kinematics there)."""
        if self._warp is not None and self._dirty.any():
            self._warp.upload(np.flatnonzero(self._dirty), self._datas)
            self._dirty[:] = False

    def _on_device(self) -> tuple:
        """With "warp": (N, nbody, 21) body frames, (N, 2) head heights and (N,) stability of
        every world as the device last left them, torch tensors there (read once per move)."""
        assert self._warp is not None
        if self._measured is None:
            head_z = self._warp.view("geom_xpos")[:, self.index.head_geoms.tolist(), 2]
            self._measured = self._warp.frames(), head_z, self._warp.stable()
        return self._measured

    def state(self) -> dict:
        """Everything that decides what the environments do next, for `load_state`: each
        one's physics (mjSTATE_INTEGRATION and the solver's warm start), its age in steps and
        the generator of its resets."""
        size = mujoco.mj_stateSize(self.model, _INTEGRATION)
        physics = np.empty((self.num_envs, size))
        warm = np.empty((self.num_envs, self.model.nv))
        self._sync()
        for i, data in enumerate(self._datas):
            mujoco.mj_getState(self.model, data, physics[i], _INTEGRATION)
            warm[i] = data.qacc_warmstart
        return {
            "physics": physics,
            "warmstart": warm,
            "elapsed": self.elapsed.copy(),
            "rng": self.rng.bit_generator.state,
        }

    def load_state(self, state: dict) -> None:
        """Continue from a `state` of environments of this model and number."""
        if state["physics"].shape != (self.num_envs, mujoco.mj_stateSize(self.model, _INTEGRATION)):
            raise ValueError(
                f"an arena state of shape {state['physics'].shape} does not fit {self.num_envs} "
                "environments of this model"
            )
        for i, data in enumerate(self._datas):
            mujoco.mj_setState(self.model, data, state["physics"][i], _INTEGRATION)
            data.qacc_warmstart[:] = state["warmstart"][i]
            mujoco.mj_forward(self.model, data)
            self._gather(i)
        self._dirty[:], self._stale = True, False
        self.elapsed[:] = state["elapsed"]
        self.rng.bit_generator.state = state["rng"]

    # ---------------------------------------------------------------- reset

    def reset(
        self,
        env_ids: Sequence[int] | np.ndarray,
        reference: ReferenceMotions,
        *,
        frames: Sequence[int] | np.ndarray | None = None,
    ) -> np.ndarray:
        """Start the given environments at reference frames (reference state initialisation).

        Each environment gets a frame drawn uniformly with the env's Generator (or the given
        `frames`), both fighters placed as in it, shifted horizontally so that the midpoint of
        their pelvises is the origin; a fighter whose lowest geom would be below the floor is
        moved up or down until its lowest point touches z = 0. Velocities follow
        `EnvConfig.reset_velocity`; a share `EnvConfig.standing_share` of starts has both
        fighters standing still in the reference's stance instead (their guard, or the rest
        pose: `standing_like`).

        Args:
            env_ids: indices of the environments, or a (N,) bool mask.
            reference: the frames to start from.
            frames: optional frame index per environment, instead of random ones.

        Returns:
            (len(env_ids), 2, 274) the reset environments' observations.
        """
        ids = _check_ids(env_ids, self.num_envs)
        if not isinstance(reference, ReferenceMotions):
            raise ValueError(
                f"reference must be a ReferenceMotions, got {type(reference).__name__}"
            )
        if frames is None:
            picks = self.rng.integers(reference.num_frames, size=len(ids))
        else:
            picks = np.asarray(frames).reshape(-1)
            if (
                picks.shape != ids.shape
                or not np.issubdtype(picks.dtype, np.integer)
                or (picks.size and (picks.min() < 0 or picks.max() >= reference.num_frames))
            ):
                raise ValueError(
                    f"frames must be {len(ids)} integers in [0, {reference.num_frames}), "
                    f"got {frames!r}"
                )
        qpos0, qpos1 = centred_pair(reference.qpos0[picks], reference.qpos1[picks])
        qvel = [
            start_velocities(v[picks], self.config.reset_velocity, self.config.reset_speed_limit)
            for v in (reference.qvel0, reference.qvel1)
        ]
        if self.config.standing_share > 0:
            standing = self.rng.random(len(ids)) < self.config.standing_share
            stance = (None, None) if reference.stance is None else reference.stance
            for qpos, v, hinges in zip((qpos0, qpos1), qvel, stance, strict=True):
                qpos[standing] = standing_like(qpos[standing], hinges)
                v[standing] = 0.0
        return self._start(ids, np.stack([qpos0, qpos1], 1), np.stack(qvel, 1), ground=True)

    def set_states(
        self, env_ids: Sequence[int] | np.ndarray, qpos: np.ndarray, qvel: np.ndarray
    ) -> np.ndarray:
        """Start the given environments with both agents exactly at ``qpos`` (n, 2, 35) moving
        at ``qvel`` (n, 2, 34), as given: no centring, no grounding, no standing starts (a
        tracking episode's start, `models.maaip.tracking`). Returns their observations
        (n, 2, 274)."""
        ids = _check_ids(env_ids, self.num_envs)
        q = np.asarray(qpos, dtype=np.float64)
        v = np.asarray(qvel, dtype=np.float64)
        if q.shape != (len(ids), NUM_AGENTS, NQ) or not np.isfinite(q).all():
            raise ValueError(f"qpos must be finite with shape ({len(ids)}, 2, {NQ}), got {q.shape}")
        if v.shape != (len(ids), NUM_AGENTS, NV) or not np.isfinite(v).all():
            raise ValueError(f"qvel must be finite with shape ({len(ids)}, 2, {NV}), got {v.shape}")
        return self._start(ids, q, v, ground=False)

    def _start(self, ids: np.ndarray, qpos: np.ndarray, qvel: np.ndarray, *, ground: bool):
        """Environments ``ids`` reset (`mj_resetData`) and started with both agents at ``qpos``
        (n, 2, 35) moving at ``qvel`` (n, 2, 34); with ``ground``, each fighter is moved up or
        down until its lowest point touches the floor (a lifted frame may float or sink, and a
        start in the air is a drop the policy did not choose). Their observations (n, 2, 274):
        with "warp" computed on the device, where the starts are made, as a torch tensor."""
        agents = self.index.agents
        mine = [np.flatnonzero(self.index.agent_of_geom == a) for a in range(NUM_AGENTS)]
        self.elapsed[ids] = 0
        if self._warp is not None:
            return self._start_on_device(ids, qpos, qvel, mine if ground else None)
        for k, i in enumerate(ids):
            data = self._datas[i]
            mujoco.mj_resetData(self.model, data)
            for a, agent in enumerate(agents):
                data.qpos[agent.qpos] = qpos[k, a]
                data.qvel[agent.qvel] = qvel[k, a]
            if ground:
                mujoco.mj_kinematics(self.model, data)
                for a, agent in enumerate(agents):
                    data.qpos[agent.qpos_start + 2] -= geom_bottoms(self.model, data, mine[a]).min()
            self._gather(i)
        return self.observe(ids)

    def _start_on_device(self, ids: np.ndarray, qpos: np.ndarray, qvel: np.ndarray, ground):
        """`_start` with "warp": the starts go up as they are and are grounded there (``ground``:
        each agent's geoms, or None)."""
        assert self._warp is not None
        warp = self._warp
        self._upload_dirty()
        full_q = np.tile(self.model.qpos0, (len(ids), 1))
        full_v = np.zeros((len(ids), self.model.nv))
        for a, agent in enumerate(self.index.agents):
            full_q[:, agent.qpos] = qpos[:, a]
            full_v[:, agent.qvel] = qvel[:, a]
        import torch

        rows = torch.as_tensor(ids, device=warp.torch_device)
        warp.start(rows, *(torch.as_tensor(x, device=rows.device) for x in (full_q, full_v)))
        if ground:
            warp.refresh(velocities=False)
            xpos, xmat = warp.view("geom_xpos")[rows], warp.view("geom_xmat")[rows]
            lows = [
                bottoms(self.model, geoms, xpos[:, geoms.tolist()], xmat[:, geoms.tolist()])
                for geoms in ground
            ]
            for agent, low in zip(self.index.agents, lows, strict=True):
                warp.view("qpos")[rows, agent.qpos_start + 2] -= low.amin(dim=1)
        warp.refresh()
        self._measured, self._stale = None, True
        frames = self._on_device()[0][rows]
        return _observations(body_state_from_frames(frames, self._body_ids))

    def place(
        self, env_id: int, agent: int, qpos: np.ndarray, *, ground: bool = True
    ) -> np.ndarray:
        """Put one agent of one environment at rest at ``qpos`` (35,), with `ground` moved up
        or down until its lowest point touches the floor (as `reset` does), the other agent
        left as it is. Returns that environment's observations (2, 274)."""
        q = np.asarray(qpos, dtype=np.float64)
        if q.shape != (NQ,) or not np.isfinite(q).all():
            raise ValueError(f"qpos must be {NQ} finite numbers, got shape {q.shape}")
        (i,) = _check_ids([env_id], self.num_envs)
        index = self.index.agents[agent]
        self._sync()  # the other agent as it is now
        data = self._datas[i]
        self._dirty[i] = True
        data.qpos[index.qpos] = q
        data.qvel[index.qvel] = 0.0
        if ground:
            mujoco.mj_kinematics(self.model, data)
            mine = np.flatnonzero(self.index.agent_of_geom == agent)
            data.qpos[index.qpos_start + 2] -= geom_bottoms(self.model, data, mine).min()
        self._gather(i)
        return self.observe(np.array([i]))[0]

    # ---------------------------------------------------------------- observe

    def body_states(self, env_ids: np.ndarray | None = None) -> BodyState:
        """Both agents' BodyState in the given environments (all by default), leading (n, 2),
        as the last step, reset or placement left them."""
        ids = np.arange(self.num_envs) if env_ids is None else np.asarray(env_ids)
        self._sync()
        return self._states(self._frames[ids])

    def _states(self, frames: np.ndarray) -> BodyState:
        """(n, 2) BodyState from (n, nbody, 21) `world_frames`, in one vectorised pass."""
        return body_state_from_frames(frames, self._body_ids)

    def observe(self, env_ids: np.ndarray | None = None) -> np.ndarray:
        """(n, 2, 274) observations of the given environments (all by default): agent k sees
        itself and agent 1 - k (`models.humanoid.observations.observation`)."""
        return _observations(self.body_states(env_ids))

    def heading_inputs(self, targets: np.ndarray) -> np.ndarray:
        """(N, 2, 2) the task input of MAAIP §5.4's heading task: each agent's target direction
        on the floor, ``targets`` (N, 2) world yaws, in its own heading frame (the cosine and
        sine of the target yaw minus the agent's). With "warp", read and computed on the
        device, a torch tensor there."""
        agents = self.index.agents
        if self._warp is None:
            quats = np.array([[d.qpos[a.qpos][ROOT_QUAT] for a in agents] for d in self._datas])
        else:
            self._upload_dirty()
            qpos = self._warp.view("qpos").double()
            rows = [qpos[:, a.qpos][:, ROOT_QUAT] for a in agents]
            quats = array_namespace(qpos).stack(rows, axis=1)
        xp = array_namespace(quats)
        relative = xp.asarray(targets, device=device(quats)) - heading_yaw(quats)
        return xp.stack([xp.cos(relative), xp.sin(relative)], axis=-1)

    # ---------------------------------------------------------------- step

    def step(self, actions: np.ndarray, puppet: Puppet | None = None) -> StepResult:
        """Advance every environment by one policy step.

        Args:
            actions: (N, 2, 28) finite actions of agent 0 and agent 1 (MAAIP §4.2); a
                puppet's are ignored.
            puppet: an agent to move through given poses instead (module docstring).

        Returns:
            StepResult for every environment (module docstring: damage, falls, time-outs).
        """
        a = self._actions(actions)
        targets = joint_targets(a, self._ctrlrange)
        xp = array_namespace(targets)
        ctrl = xp.zeros((self.num_envs, self.model.nu), dtype=a.dtype, device=device(a))
        for agent in range(NUM_AGENTS):
            ids = xp.asarray(self.index.actuators[agent], device=device(a))
            ctrl[:, ids] = targets[:, agent]
        paths = None if puppet is None else self._puppet_paths(puppet)
        damage, floor = self._advance(ctrl, contacts=True, paths=paths)
        # Where the worlds are: the host's copies, or with "warp" the device's tensors.
        frames, head_z, stable = (
            (self._frames, self._head_z, self._stable) if self._warp is None else self._on_device()
        )
        with np.errstate(all="ignore"):  # an unstable environment's numbers are not finite
            states = self._states(frames)
            obs = _observations(states)
            fell = (floor | (head_z < self.config.fall_height_m)) & stable[:, None]
        unstable = ~stable
        if self._warp is not None:  # the flags the host decides resets by come down
            fell, unstable = fell.cpu().numpy(), unstable.cpu().numpy()
        if unstable.any():
            # Zeros, so that no NaN reaches the networks; the episode ends here.
            mask = xp.asarray(unstable, device=device(obs))
            obs[mask] = 0.0
            damage[mask] = 0.0
        self.elapsed += 1
        terminated = fell.any(axis=1) | unstable
        truncated = (self.elapsed >= self.config.max_steps) & ~terminated
        return StepResult(
            observation=obs,
            self_observation=obs[..., :SELF_DIM],
            terminated=terminated,
            truncated=truncated,
            fell=fell,
            damage=damage,
            unstable=unstable,
            body=states,
        )

    def _actions(self, actions: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
        """``actions`` (N, 2, 28), NumPy or torch, checked, in float64 where the physics runs:
        on the host, or with "warp" on its device (a torch tensor there)."""
        if self._warp is None:
            a = to_host(actions)
        else:
            import torch

            a = torch.as_tensor(actions).to(self._warp.torch_device, torch.float64)
        want = (self.num_envs, NUM_AGENTS, NUM_ACTUATED)
        if tuple(a.shape) != want:
            raise ValueError(f"actions must have shape {want} (N, agents, 28), got {a.shape}")
        xp = array_namespace(a)
        if not bool(xp.all(xp.isfinite(a))):
            host = to_host(a)
            bad = np.argwhere(~np.isfinite(host))[0]
            raise ValueError(
                f"actions must be finite; env {bad[0]}, agent {bad[1]}, action {bad[2]} "
                f"is {host[tuple(bad)]}"
            )
        return a

    def step_physics(self, ctrl: np.ndarray | None = None) -> None:
        """Raw physics for benchmarks: `substeps` mj_step calls per environment with `ctrl`
        (N, nu) held (default zeros: every PD target at the rest pose); no contacts are read,
        no observation is made, `elapsed` does not move, and the MjData's kinematics stay
        one substep behind their state until the next `step` or `reset`."""
        if ctrl is None:
            ctrl = np.zeros((self.num_envs, self.model.nu))
        elif np.shape(ctrl) != (self.num_envs, self.model.nu):
            raise ValueError(
                f"ctrl must have shape ({self.num_envs}, {self.model.nu}), got {np.shape(ctrl)}"
            )
        self._advance(np.asarray(ctrl, dtype=np.float64), contacts=False)

    def _puppet_paths(self, puppet: Puppet) -> tuple[slice, slice, np.ndarray, np.ndarray]:
        """The puppet's qpos and qvel slices, and per environment the whole model's qpos at the
        step's start (N, nq) and a qvel (N, nv) that is the puppet's velocity to its pose."""
        if self.config.stepping != "threads":
            raise ValueError('a puppet needs EnvConfig.stepping "threads"')
        if puppet.agent not in (0, 1):
            raise ValueError(f"puppet.agent must be 0 or 1, got {puppet.agent!r}")
        qpos = np.asarray(puppet.qpos, dtype=np.float64)
        if qpos.shape != (self.num_envs, NQ) or not np.isfinite(qpos).all():
            raise ValueError(f"puppet.qpos must be finite with shape ({self.num_envs}, {NQ})")
        agent = self.index.agents[puppet.agent]
        moved_qpos, moved_qvel = agent.qpos, agent.qvel
        if puppet.root_only:
            moved_qpos = slice(agent.qpos_start, agent.qpos_start + 7)
            moved_qvel = slice(agent.qvel_start, agent.qvel_start + 6)
        starts = np.empty((self.num_envs, self.model.nq))
        velocities = np.zeros((self.num_envs, self.model.nv))
        step_s = self.config.timestep * self.config.substeps
        for i, data in enumerate(self._datas):
            starts[i] = data.qpos
            end = data.qpos.copy()
            end[moved_qpos] = qpos[i][: moved_qpos.stop - moved_qpos.start]
            mujoco.mj_differentiatePos(self.model, velocities[i], step_s, starts[i], end)
        mine = np.zeros(self.model.nv, dtype=bool)
        mine[moved_qvel] = True
        velocities[:, ~mine] = 0.0
        return moved_qpos, moved_qvel, starts, velocities

    def _advance(
        self,
        ctrl: np.ndarray,
        *,
        contacts: bool,
        paths: tuple[slice, slice, np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Hold `ctrl` (N, nu) for `substeps` physics steps in every environment. With
        `contacts`, also refresh the kinematics, fill `_frames` and `_head_z` and return each
        agent's damage (N, 2) and floor touches (N, 2); without, only step. `paths`
        (`_puppet_paths`) moves a puppet along its path before every substep."""
        if self._rollout is not None:
            return self._advance_rollout(ctrl, contacts=contacts)
        if self._warp is not None:
            return self._advance_warp(ctrl, contacts=contacts)
        damage = np.zeros((self.num_envs, NUM_AGENTS))
        floor = np.zeros((self.num_envs, NUM_AGENTS), dtype=bool)

        def run(chunk: np.ndarray) -> None:
            model, substeps, tables = self.model, self.config.substeps, self._tables
            force = np.zeros(6)
            for i in chunk:
                data = self._datas[i]
                data.ctrl[:] = ctrl[i]
                for k in range(substeps):
                    if paths is not None:
                        _move_puppet(model, data, paths, i, k * model.opt.timestep)
                    mujoco.mj_step(model, data)
                    if contacts:
                        _read_contacts(model, data, tables, damage[i], floor[i], force)
                if paths is not None:
                    _move_puppet(model, data, paths, i, substeps * model.opt.timestep)
            if contacts:
                # In the worker, so that this work overlaps with the other workers' mj_step
                # (which runs without the GIL); after the chunk's physics, which then runs back
                # to back and keeps its caches (measured: 5 % faster).
                for i in chunk:
                    self._gather(i)

        if self._pool is None:
            run(np.arange(self.num_envs))
        else:
            for future in [self._pool.submit(run, chunk) for chunk in self._chunks]:
                future.result()  # re-raises a worker's exception here
        return damage, floor

    def _gather(self, i: int) -> None:
        """Refresh environment i's kinematics and copy what the observations and the fall rule
        read into row i of `_frames` and `_head_z`."""
        data = self._datas[i]
        _refresh(self.model, data)
        world_frames(self.model, data, self._frames[i])
        self._head_z[i] = data.geom_xpos[self.index.head_geoms, 2]
        # MuJoCo's own test (mj_checkPos / mj_checkVel): not finite or beyond mjMAXVAL.
        self._stable[i] = bool(
            np.all(np.abs(data.qpos) < mujoco.mjMAXVAL)
            and np.all(np.abs(data.qvel) < mujoco.mjMAXVAL)
        )

    def _advance_rollout(
        self, ctrl: np.ndarray, *, contacts: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        assert self._rollout is not None
        model, n = self.model, self.num_envs
        state = np.empty((n, self._nstate))
        for i, data in enumerate(self._datas):
            mujoco.mj_getState(model, data, state[i], _FULL)
        control = np.repeat(ctrl[:, None, :], self.config.substeps, axis=1)
        # The returned states lack the solver's warm start, so every call starts it cold
        # (zeros), whatever the MjData hold; within the call it carries over as in mj_step.
        states, sensordata = self._rollout.rollout(
            model, self._scratch, state, control, initial_warmstart=np.zeros((n, model.nv))
        )
        for i, data in enumerate(self._datas):
            mujoco.mj_setState(model, data, states[i, -1], _FULL)
            data.ctrl[:] = ctrl[i]
            if contacts:
                self._gather(i)
        if not contacts:
            return np.zeros((n, NUM_AGENTS)), np.zeros((n, NUM_AGENTS), dtype=bool)
        assert self.index.sensors is not None
        return sensor_contacts(sensordata, self.index.sensors)

    def _advance_warp(self, ctrl, *, contacts: bool):
        assert self._warp is not None
        self._upload_dirty()
        sensordata = self._warp.advance(ctrl, self.config.substeps)
        self._measured, self._stale = None, True
        if not contacts:
            n = self.num_envs
            return np.zeros((n, NUM_AGENTS)), np.zeros((n, NUM_AGENTS), dtype=bool)
        assert self.index.sensors is not None
        return sensor_contacts(sensordata, self.index.sensors)
