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

The physics behind the step is one backend, chosen once from `EnvConfig.stepping` and called
through one interface (`models.arena.stepping`: "rollout", "threads" or "warp"). Episode starts
are chosen in `models.arena.starts`; the puppet of live sparring is `models.arena.puppet`.

Shape letters: N environments, M reference frames, 2 agents.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import mujoco
import numpy as np
from array_api_compat import array_namespace, device, is_torch_array

from models.arena.config import EnvConfig
from models.arena.mjcf import NUM_AGENTS, arena_index, arena_mjcf
from models.arena.puppet import Puppet
from models.arena.starts import ReferenceMotions, choose_starts, place_agent
from models.arena.stepping import BACKENDS, Stepping
from models.arena.stepping.host import HostWorlds, to_host
from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import (
    NQ,
    NUM_ACTUATED,
    NV,
    action_to_joint_targets,
    heading_yaw,
)
from models.humanoid.observations import (
    SELF_DIM,
    BodyState,
    body_state_from_frames,
    observation,
    self_observation,
)

if TYPE_CHECKING:  # torch only where Warp's observations are (annotations)
    import torch

_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION


@dataclass(frozen=True, eq=False)
class StepResult:
    """What one `ArenaEnv.step` returns.

    With stepping "warp", `observation`, `self_observation`, `damage` and `body` are torch
    tensors (float32) on Warp's device, where they were computed; the flags, which the host
    decides resets by, are NumPy arrays with every stepping.

    Attributes:
        observation: (N, 2, 274) each agent's o_{t+1} = [o^self, o^opp] (MAAIP §4.2); a
            step asked for no opponent observation (a tracker's) gives o^self alone, (N, 2, 223).
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
        backend = BACKENDS[config.stepping]
        xml = arena_mjcf(bones, timestep=config.timestep, contact_sensors=backend.contact_sensors)
        self.model = mujoco.MjModel.from_xml_string(xml)
        # An unstable simulation is caught here (`StepResult.unstable`) rather than silently
        # restarted by MuJoCo at the model's rest state, which would read as a teleport.
        self.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
        self.index = arena_index(self.model)
        self.elapsed = np.zeros(config.num_envs, dtype=int)
        self._ctrlrange = self.model.actuator_ctrlrange[self.index.actuators]  # (2, 28, 2)
        self._body_ids = np.stack([agent.body_ids for agent in self.index.agents])  # (2, 15)
        self._host = HostWorlds(self.model, self.index, config.num_envs)
        self._stepping: Stepping = backend.make(self._host, config, device)

    def close(self) -> None:
        """End the worker threads."""
        self._stepping.close()

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
        self._stepping.sync()
        self._stepping.written(slice(None))
        return self._host.datas

    def state(self) -> dict:
        """Everything that decides what the environments do next, for `load_state`: each
        one's physics (mjSTATE_INTEGRATION and the solver's warm start), its age in steps and
        the generator of its resets."""
        size = mujoco.mj_stateSize(self.model, _INTEGRATION)
        physics = np.empty((self.num_envs, size))
        warm = np.empty((self.num_envs, self.model.nv))
        self._stepping.sync()
        for i, data in enumerate(self._host.datas):
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
        for i, data in enumerate(self._host.datas):
            mujoco.mj_setState(self.model, data, state["physics"][i], _INTEGRATION)
            data.qacc_warmstart[:] = state["warmstart"][i]
            mujoco.mj_forward(self.model, data)
            self._host.gather(i)
        self._stepping.written(slice(None))
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
        pose: `standing_like`). `models.arena.starts.choose_starts` chooses them.

        Args:
            env_ids: indices of the environments, or a (N,) bool mask.
            reference: the frames to start from.
            frames: optional frame index per environment, instead of random ones.

        Returns:
            (len(env_ids), 2, 274) the reset environments' observations.
        """
        ids = _check_ids(env_ids, self.num_envs)
        qpos, qvel = choose_starts(reference, len(ids), self.config, self.rng, frames)
        # With "warp" observed on the device, where the starts are made, as a torch tensor.
        return _observations(self._states(self._start(ids, qpos, qvel, ground=True)))

    def set_states(
        self,
        env_ids: Sequence[int] | np.ndarray,
        qpos: np.ndarray,
        qvel: np.ndarray,
        *,
        ground: bool = False,
    ) -> None:
        """Start the given environments with both agents exactly at ``qpos`` (n, 2, 35) moving
        at ``qvel`` (n, 2, 34), as given: no centring, no standing starts, and with ``ground``
        each fighter moved up or down until its lowest point touches the floor (a tracking
        episode's start, `models.tracking`, which observes them its own way from
        `body_states`)."""
        ids = _check_ids(env_ids, self.num_envs)
        q = np.asarray(qpos, dtype=np.float64)
        v = np.asarray(qvel, dtype=np.float64)
        if q.shape != (len(ids), NUM_AGENTS, NQ) or not np.isfinite(q).all():
            raise ValueError(f"qpos must be finite with shape ({len(ids)}, 2, {NQ}), got {q.shape}")
        if v.shape != (len(ids), NUM_AGENTS, NV) or not np.isfinite(v).all():
            raise ValueError(f"qvel must be finite with shape ({len(ids)}, 2, {NV}), got {v.shape}")
        self._start(ids, q, v, ground=ground)

    def _start(self, ids: np.ndarray, qpos: np.ndarray, qvel: np.ndarray, *, ground: bool):
        """Environments ``ids`` reset (`mj_resetData`) and started with both agents at ``qpos``
        (n, 2, 35) moving at ``qvel`` (n, 2, 34); with ``ground``, each fighter is moved up or
        down until its lowest point touches the floor (a lifted frame may float or sink, and a
        start in the air is a drop the policy did not choose). Their `world_frames` (n, nbody,
        21), on Warp's device with "warp"."""
        mine = [np.flatnonzero(self.index.agent_of_geom == a) for a in range(NUM_AGENTS)]
        self.elapsed[ids] = 0
        return self._stepping.start(ids, qpos, qvel, mine if ground else None)

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
        self._stepping.sync()  # the other agent as it is now
        self._stepping.written(np.array([i]))
        place_agent(self.model, self._host.datas[i], self.index, agent, q, ground=ground)
        self._host.gather(i)
        return self.observe(np.array([i]))[0]

    # ---------------------------------------------------------------- observe

    def body_states(self, env_ids: np.ndarray | None = None) -> BodyState:
        """Both agents' BodyState in the given environments (all by default), leading (n, 2),
        as the last step, reset or placement left them."""
        ids = np.arange(self.num_envs) if env_ids is None else np.asarray(env_ids)
        self._stepping.sync()
        return self._states(self._host.frames[ids])

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
        quats = self._stepping.root_quats()
        xp = array_namespace(quats)
        relative = xp.asarray(targets, device=device(quats)) - heading_yaw(quats)
        return xp.stack([xp.cos(relative), xp.sin(relative)], axis=-1)

    # ---------------------------------------------------------------- step

    def step(
        self,
        actions: np.ndarray,
        puppet: Puppet | None = None,
        *,
        pushes: np.ndarray | None = None,
        opponent: bool = True,
    ) -> StepResult:
        """Advance every environment by one policy step.

        Args:
            actions: (N, 2, 28) finite actions of agent 0 and agent 1 (MAAIP §4.2); a
                puppet's are ignored.
            puppet: an agent to move through given poses instead (`models.arena.puppet`).
            pushes: (N, nbody, 6) finite forces (N) and torques (N m) on each body's centre of
                mass, in world axes (MuJoCo's xfrc_applied), held over the step's substeps
                and gone after it: a push (`models.arena.pushes`). None: none.
            opponent: whether to observe the other fighter too (o^opp); a tracker reads o^self
                alone, and the opponent's part is most of the observation's cost.

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
        paths = None if puppet is None else self._stepping.puppet_paths(puppet)
        if pushes is not None:
            pushes = np.asarray(pushes, dtype=np.float64)
            want = (self.num_envs, self.model.nbody, 6)
            if pushes.shape != want or not np.isfinite(pushes).all():
                raise ValueError(f"pushes must be finite with shape {want}, got {pushes.shape}")
        damage, floor = self._stepping.advance(ctrl, contacts=True, paths=paths, pushes=pushes)
        # Where the worlds are: the host's copies, or with "warp" the device's tensors.
        frames, head_z, stable = self._stepping.measured()
        with np.errstate(all="ignore"):  # an unstable environment's numbers are not finite
            states = self._states(frames)
            obs = _observations(states) if opponent else self_observation(states)
            fell = (floor | (head_z < self.config.fall_height_m)) & stable[:, None]
        unstable = ~stable
        # The flags the host decides resets by come down (with "warp").
        fell, unstable = _on_host(fell), _on_host(unstable)
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
        a = self._stepping.physics_array(actions)
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
        self._stepping.advance(np.asarray(ctrl, dtype=np.float64), contacts=False)


def _on_host(flags: np.ndarray | torch.Tensor) -> np.ndarray:
    """A step's flags (NumPy, or with "warp" torch bools on its device) as a NumPy array."""
    return flags.cpu().numpy() if is_torch_array(flags) else flags
