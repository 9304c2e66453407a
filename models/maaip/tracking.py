"""A tracker: each fighter follows reference clips in the arena (`TrainerConfig.objective` 'track').

The method, as physics-based character animation practises it:
- Reference state initialisation (DeepMimic, Peng et al., ACM TOG 37(4), 2018): an
  episode starts at a frame drawn uniformly from every frame (but the last) of every clip,
  with the clip's velocities; the body is put exactly where the clip is.
- The action is a correction: the PD targets are the clip's next frame plus the policy's
  output (DReCon, Bergamin et al., ACM TOG 38(6), 2019), so an untrained policy already plays
  the clip back through the physics. The correction is added in MAAIP's action space
  (exponential maps for the 3-DoF joints, angles for elbows and knees).
- The observation is the agent's own o^self (223, the observation MAAIP's policy sees of
  itself) and the next reference frame (`tracking_input`, 228): that frame's o^self and where
  its pelvis is (position and heading) from the agent's. Nothing of the other fighter.
- The reward is DeepMimic's imitation reward (`deepmimic_reward`).
- Early termination: a fall (the arena's rule) or the pelvis further than
  `TrackConfig.root_limit_m` from the reference's. Reaching the clip's last frame is a time-out.

Both fighters of an arena track, each its own clip drawn independently: the physics steps both
bodies anyway, so two agents double the samples for the same cost. Each clip is moved along the
floor so that its start frame's pelvis is at y = -separation/2 (agent 0) or +separation/2
(agent 1), heading kept, and they never meet. An arena's episode ends when either agent's
does; the other agent's ending is then a time-out for it (bootstrapped), not a termination.

Errors (`body_error`, `root_error`): the mean over the 15 bodies of the distance between the
simulated and the reference body origins, each relative to its own pelvis (world axes, so a
turned body counts), and the distance between the pelvises.

Shape letters: T frames, F frames of all clips, N environments, 2 agents, B bodies (15).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.compiled import body_states, humanoid_index, velocities
from models.humanoid.kinematics import (
    BODY_NAMES,
    NQ,
    NUM_ACTUATED,
    NV,
    PARENTS,
    heading_frame_of_matrix,
    joint_targets_to_action,
)
from models.humanoid.observations import SELF_DIM, BodyState, self_observation
from models.maaip.config import NUM_AGENTS, EnvConfig, TrackConfig, TrainerConfig
from models.maaip.env import ArenaEnv, StepResult, to_host
from models.maaip.networks import CentralValue, Policy, action_stds

TRACK_INPUT_DIM = SELF_DIM + 5  # the next frame's o^self, its pelvis (3) and heading (cos, sin)
TRACK_OBSERVATION_DIM = SELF_DIM + TRACK_INPUT_DIM  # 451
# The bodies whose joints the pose and velocity terms sum over: all but the hands, welded to
# the forearms. The pelvis's "joint" is its rotation (and angular velocity) in the world.
JOINT_BODIES = np.array([i for i, b in enumerate(BODY_NAMES) if not b.endswith("_hand")])
END_EFFECTORS = np.array(
    [BODY_NAMES.index(b) for b in ("right_hand", "left_hand", "right_foot", "left_foot")]
)
REWARD_TERMS = ("pose", "velocity", "end_effector", "com")
_PARENT = np.array([max(p, 0) for p in PARENTS])


# --------------------------------------------------------------------------
# Reference clips
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ReferenceClip:
    """One clip on one humanoid, per frame, on the policy's grid.

    Attributes:
        name: the clip's name.
        qpos: (T, 35) the humanoid's qpos.
        qvel: (T, 34) by central differences (`models.humanoid.compiled.velocities`).
        states: BodyState (T,) of the frames.
        observation: (T, 223) o^self of each frame.
        com: (T, 3) the centre of mass.
        actions: (T, 28) each frame's hinge angles as MAAIP actions (the PD targets that hold it).
        body_mass: (15,) the bodies' masses (kg), for `centre_of_mass`.
        body_com: (15, 3) each body's centre of mass in its own frame (m).
    """

    name: str
    qpos: np.ndarray
    qvel: np.ndarray
    states: BodyState
    observation: np.ndarray
    com: np.ndarray
    actions: np.ndarray
    body_mass: np.ndarray
    body_com: np.ndarray

    @property
    def num_frames(self) -> int:
        return len(self.qpos)


def centre_of_mass(state: BodyState, body_mass: np.ndarray, body_com: np.ndarray) -> np.ndarray:
    """(..., 3) the whole humanoid's centre of mass from its bodies' poses, masses (15,) and
    local centres of mass (15, 3) (MuJoCo's body_mass and body_ipos)."""
    points = state.pos + np.einsum("...ij,...j->...i", state.rot, body_com)
    return np.einsum("...bi,b->...i", points, body_mass) / body_mass.sum()


def reference_clip(name: str, qpos: np.ndarray, bones: BoneLengths, *, fps: float) -> ReferenceClip:
    """A clip of qpos (T, 35) at ``fps`` on the humanoid with ``bones``, ready to track.

    Raises:
        ValueError: naming the clip, if it has fewer than 2 frames or is not finite.
    """
    q = np.asarray(qpos, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != NQ or len(q) < 2 or not np.isfinite(q).all():
        raise ValueError(f"clip {name!r}: qpos must be finite, (T >= 2, {NQ}), got {q.shape}")
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(bones))
    index = humanoid_index(model)
    qvel = velocities(model, q, fps)
    states = body_states(model, q, qvel, index)
    mass = model.body_mass[index.body_ids].copy()
    local = model.body_ipos[index.body_ids].copy()
    return ReferenceClip(
        name=name,
        qpos=q,
        qvel=qvel,
        states=states,
        observation=self_observation(states),
        com=centre_of_mass(states, mass, local),
        actions=joint_targets_to_action(q[:, 7:]),
        body_mass=mass,
        body_com=local,
    )


@dataclass(frozen=True, eq=False)
class TrackingData:
    """What a tracker trains on: each agent's clips on its own humanoid.

    Attributes:
        key: names the data (a dataset's key, or e.g. "clips:walk,punch").
        bones: agent 0's and agent 1's bone lengths.
        clips: agent 0's clips and agent 1's (`reference_clip` on that agent's bones).
        fps: the clips' frame rate, which must be the policy's (`EnvConfig.policy_hz`).
    """

    key: str
    bones: tuple[BoneLengths, BoneLengths]
    clips: tuple[tuple[ReferenceClip, ...], tuple[ReferenceClip, ...]]
    fps: float


def tracking_data(
    clips: tuple[Mapping[str, np.ndarray], Mapping[str, np.ndarray]],
    bones: tuple[BoneLengths, BoneLengths],
    *,
    fps: float,
    key: str,
) -> TrackingData:
    """TrackingData from each agent's clips as qpos arrays by name (retargeted onto its bones)."""
    if len(clips) != NUM_AGENTS or not all(clips):
        raise ValueError("clips must hold one non-empty mapping of clips per agent")
    made = tuple(
        tuple(reference_clip(name, q, bones[a], fps=fps) for name, q in clips[a].items())
        for a in range(NUM_AGENTS)
    )
    return TrackingData(key, bones, made, float(fps))  # type: ignore[arg-type]


# --------------------------------------------------------------------------
# The reward and the errors (pure, batched)
# --------------------------------------------------------------------------


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


def tracking_input(sim: BodyState, ref: BodyState, ref_observation: np.ndarray) -> np.ndarray:
    """(..., 228) what the policy is told of the frame to reach: its o^self (``ref_observation``
    (..., 223)), then the reference pelvis relative to the agent's in the agent's heading frame
    (3) and the cosine and sine of the reference heading's yaw relative to the agent's."""
    mine = heading_frame_of_matrix(sim.rot[..., 0, :, :])
    theirs = heading_frame_of_matrix(ref.rot[..., 0, :, :])
    offset = ((ref.pos[..., 0, :] - sim.pos[..., 0, :])[..., None, :] @ mine)[..., 0, :]
    turn = mine.swapaxes(-1, -2) @ theirs
    return np.concatenate([ref_observation, offset, turn[..., 0, 0:1], turn[..., 1, 0:1]], axis=-1)


# --------------------------------------------------------------------------
# The tracker: episodes in an ArenaEnv
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class _Frames:
    """One agent's clips end to end (F frames, one `ReferenceClip`), and where each starts."""

    clip: ReferenceClip
    start: np.ndarray  # (C,)
    last: np.ndarray  # (C,) flat index of each clip's last frame
    startable: np.ndarray  # flat indices of every frame but the clips' last


def _frames(clips: Sequence[ReferenceClip]) -> _Frames:
    lengths = np.array([c.num_frames for c in clips])
    start = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    last = start + lengths - 1
    # The per-frame fields joined; the body's masses are one humanoid's, the first clip's.
    joined = {
        f.name: np.concatenate([getattr(c, f.name) for c in clips])
        for f in dataclasses.fields(ReferenceClip)
        if f.name not in ("name", "states", "body_mass", "body_com")
    }
    states = BodyState(
        *(
            np.concatenate([getattr(c.states, f.name) for c in clips])
            for f in dataclasses.fields(BodyState)
        )
    )
    clip = ReferenceClip(
        name="+".join(c.name for c in clips),
        states=states,
        body_mass=clips[0].body_mass,
        body_com=clips[0].body_com,
        **joined,
    )
    return _Frames(clip, start, last, np.setdiff1d(np.arange(lengths.sum()), last))


@dataclass(frozen=True, eq=False)
class TrackStep:
    """One `Tracker.step`: the arena's StepResult's fields the trainer reads, and the tracking.

    Attributes:
        observation: (N, 2, 451) each agent's o^self and `tracking_input` after the step.
        terminated: (N,) an agent fell, drifted or the simulation blew up.
        truncated: (N,) an agent reached its clip's end, or the episode its time limit.
        terminal: (N, 2) which agents' own episodes ended terminally (the other's is a time-out).
        fell, damage, unstable: as in StepResult.
        reward: (N, 2) DeepMimic's reward (0 where unstable).
        terms: (N, 2, 4) its terms, REWARD_TERMS order.
        body_error, root_error: (N, 2) metres against the frame just reached.
    """

    observation: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    terminal: np.ndarray
    fell: np.ndarray
    damage: np.ndarray
    unstable: np.ndarray
    reward: np.ndarray
    terms: np.ndarray
    body_error: np.ndarray
    root_error: np.ndarray

    @property
    def done(self) -> np.ndarray:
        return self.terminated | self.truncated


class Tracker:
    """Tracking episodes of N arenas, both agents: which clip and frame each agent is at and
    where its clip was put (module docstring). `state` and `load_state` checkpoint it."""

    def __init__(self, data: TrackingData, config: TrackConfig, env: EnvConfig):
        if data.fps != env.policy_hz:
            raise ValueError(
                f"the clips of {data.key!r} are at {data.fps} fps, the policy steps at "
                f"{env.policy_hz} Hz: retarget them at the policy's rate"
            )
        num_envs = env.num_envs
        self.data, self.config = data, config
        self.frames = tuple(_frames(clips) for clips in data.clips)
        self.flat = np.zeros((num_envs, NUM_AGENTS), dtype=int)  # index into `frames`
        self.offset = np.zeros((num_envs, NUM_AGENTS, 3))  # added to the clip's positions
        self.slots = np.array(
            [[0.0, -config.separation_m / 2, 0.0], [0, config.separation_m / 2, 0]]
        )

    def state(self) -> dict:
        return {"flat": self.flat.copy(), "offset": self.offset.copy()}

    def load_state(self, state: dict) -> None:
        self.flat[:] = state["flat"]
        self.offset[:] = state["offset"]

    def clip_and_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) each agent's clip index and frame in it."""
        clip = np.stack(
            [
                np.searchsorted(f.start, self.flat[:, a], side="right") - 1
                for a, f in enumerate(self.frames)
            ],
            axis=1,
        )
        start = np.stack([f.start[clip[:, a]] for a, f in enumerate(self.frames)], axis=1)
        return clip, self.flat - start

    def reference(self, flat: np.ndarray, ids: np.ndarray | slice = slice(None)) -> BodyState:
        """(n, 2) the reference frames ``flat`` (n, 2) of environments ``ids``, where placed."""
        parts = [f.clip.states[flat[:, a]] for a, f in enumerate(self.frames)]
        shift = self.offset[ids][:, :, None, :]
        pos = np.stack([p.pos for p in parts], axis=1) + shift
        rot, lin, ang = (
            np.stack([getattr(p, k) for p in parts], axis=1) for k in ("rot", "lin_vel", "ang_vel")
        )
        return BodyState(pos, rot, lin, ang)

    def _next(self, ids: np.ndarray | slice = slice(None)) -> np.ndarray:
        """(n, 2) the flat index of each agent's next frame (its last at the clip's end)."""
        flat = self.flat[ids]
        lasts = np.stack(
            [f.last[np.searchsorted(f.last, flat[:, a])] for a, f in enumerate(self.frames)], 1
        )
        return np.minimum(flat + 1, lasts)

    def observation(self, sim: BodyState, ids: np.ndarray | slice = slice(None)) -> np.ndarray:
        """(n, 2, 451) o^self of ``sim`` (n, 2) and the next reference frame (`tracking_input`)."""
        nxt = self._next(ids)
        ref_obs = np.stack([f.clip.observation[nxt[:, a]] for a, f in enumerate(self.frames)], 1)
        given = tracking_input(sim, self.reference(nxt, ids), ref_obs)
        return np.concatenate([self_observation(sim), given], -1)

    def reset(
        self,
        env: ArenaEnv,
        ids: np.ndarray,
        rng: np.random.Generator,
        *,
        clips: np.ndarray | None = None,
        as_filmed: bool = False,
    ) -> np.ndarray:
        """Start environments ``ids`` (n,): each agent at a frame drawn uniformly from every
        frame but the last of every one of its clips (or at the first frame of ``clips`` (n, 2)),
        with the clip's velocities, placed at its slot. ``as_filmed``: each agent's clip k is
        one of the two fighters of one piece of footage (the same length), both agents start at
        the same frame of it and where the footage has them. Returns their observations
        (n, 2, 451)."""
        ids = np.asarray(ids, dtype=int)
        qpos = np.empty((len(ids), NUM_AGENTS, NQ))
        qvel = np.empty((len(ids), NUM_AGENTS, NV))
        if as_filmed and not np.array_equal(self.frames[0].last, self.frames[1].last):
            raise ValueError("as_filmed: the agents' clips must pair up, clip k of equal length")
        for a, f in enumerate(self.frames):
            if clips is not None:
                flat = f.start[np.asarray(clips)[:, a]]
            elif as_filmed and a == 1:
                flat = self.flat[ids, 0]  # agent 0's frame: the same step of the same footage
            else:
                flat = f.startable[rng.integers(len(f.startable), size=len(ids))]
            self.flat[ids, a] = flat
            if as_filmed:
                self.offset[ids, a] = 0.0
            else:
                self.offset[ids, a] = self.slots[a] - f.clip.qpos[flat, :3] * [1, 1, 0]
            qpos[:, a] = f.clip.qpos[flat]
            qpos[:, a, :3] += self.offset[ids, a]
            qvel[:, a] = f.clip.qvel[flat]
        env.set_states(ids, qpos, qvel)
        return self.observation(env.body_states(ids), ids)

    def actions(self, corrections: np.ndarray) -> np.ndarray:
        """(N, 2, 28) the arena's actions: each agent's next reference frame (the PD targets
        that hold it) plus its ``corrections`` (N, 2, 28) (DReCon)."""
        nxt = self._next()
        held = np.stack([f.clip.actions[nxt[:, a]] for a, f in enumerate(self.frames)], 1)
        return held + corrections

    def step(self, env: ArenaEnv, corrections: np.ndarray) -> TrackStep:
        """One policy step of every environment: PD targets from `actions`, then every agent
        on its next frame, rewarded and checked against it."""
        if corrections.shape != (env.num_envs, NUM_AGENTS, NUM_ACTUATED):
            raise ValueError(
                f"corrections must have shape ({env.num_envs}, 2, {NUM_ACTUATED}), "
                f"got {corrections.shape}"
            )
        result: StepResult = env.step(self.actions(corrections))
        self.flat = self._next()
        # The rewards are computed on the host (with "warp" the bodies come down from the device).
        body = result.body
        sim = BodyState(*(to_host(x) for x in (body.pos, body.rot, body.lin_vel, body.ang_vel)))
        ref = self.reference(self.flat)
        sim_com = np.stack(
            [
                centre_of_mass(sim[:, a], f.clip.body_mass, f.clip.body_com)
                for a, f in enumerate(self.frames)
            ],
            1,
        )
        ref_com = np.stack([f.clip.com[self.flat[:, a]] for a, f in enumerate(self.frames)], 1)
        with np.errstate(all="ignore"):  # an unstable environment's numbers are not finite
            terms = deepmimic_reward(sim, ref, sim_com, ref_com + self.offset, config=self.config)
            body, root = body_error(sim, ref), root_error(sim, ref)
            drift = root > self.config.root_limit_m
            observation = self.observation(sim)
        stable = ~result.unstable
        terminal = result.fell | drift | result.unstable[:, None]
        ended = np.stack([np.isin(self.flat[:, a], f.last) for a, f in enumerate(self.frames)], 1)
        terminated = terminal.any(1)
        truncated = (ended.any(1) | result.truncated) & ~terminated
        reward = np.where(stable[:, None], terms["total"], 0.0)
        stacked = np.stack([terms[k] for k in REWARD_TERMS], -1)
        stacked[~stable] = 0.0
        observation[~stable] = 0.0
        return TrackStep(
            observation=observation,
            terminated=terminated,
            truncated=truncated,
            terminal=terminal,
            fell=result.fell,
            damage=to_host(result.damage),
            unstable=result.unstable,
            reward=reward,
            terms=stacked,
            body_error=np.where(stable[:, None], body, np.nan),
            root_error=np.where(stable[:, None], root, np.nan),
        )


# --------------------------------------------------------------------------
# Networks and the gate
# --------------------------------------------------------------------------


def tracking_networks(
    config: TrainerConfig, *, generator: torch.Generator
) -> tuple[Policy, CentralValue]:
    """The tracker's policy and centralised value: MAAIP's, with the tracker's observation
    (TRACK_OBSERVATION_DIM) and a mean of zero correction (no guard offset)."""
    hidden, clip = config.network.hidden_sizes, config.network.observation_clip
    policy = Policy(
        hidden=hidden,
        action_std=action_stds(config),
        obs_dim=TRACK_OBSERVATION_DIM,
        observation_clip=clip,
        generator=generator,
    )
    value = CentralValue(
        hidden=hidden, obs_dim=TRACK_OBSERVATION_DIM, observation_clip=clip, generator=generator
    )
    return policy, value


@dataclass(frozen=True)
class GateRow:
    """One clip tracked by one agent from its first frame, acting on the policy's mean.

    Attributes:
        agent, clip: who tracked which clip (its name).
        finished: it reached the clip's last frame without a fall or a drift.
        frames: the steps it tracked (the terminating one included).
        body_error_cm, root_error_cm: mean errors over those steps.
    """

    agent: int
    clip: str
    finished: bool
    frames: int
    body_error_cm: float
    root_error_cm: float


@dataclass(frozen=True)
class Gate:
    """`track_gate`'s figures: the share of runs finished (%), and the mean over runs of each
    run's mean body and root errors (cm); `rows` per run."""

    finished_pct: float
    body_error_cm: float
    root_error_cm: float
    rows: tuple[GateRow, ...]


@dataclass(frozen=True, eq=False)
class Played:
    """`play_clips`' outcome.

    Attributes:
        rows: one per agent and clip, agent by agent.
        qpos: (S, n, nq) the arena's qpos after each step, environment k playing each agent's
            clip k; an agent's run is its first ``frames`` steps (`GateRow.frames`).
        model: the arena's model (the humanoids' prefixes `models.maaip.arena.DEFAULT_PREFIXES`).
    """

    rows: tuple[GateRow, ...]
    qpos: np.ndarray
    model: mujoco.MjModel


def play_clips(
    policy: Policy, data: TrackingData, config: TrainerConfig, *, as_filmed: bool = False
) -> Played:
    """Track every clip of both agents from its first frame to its end, acting on ``policy``'s
    mean, in an arena of its own (the trainer's environments and random state are untouched).

    Environment k has each agent on its clip k (the last clip again where an agent has fewer),
    at its slot or, ``as_filmed``, where the footage has them (`Tracker.reset`); a run ends at
    the clip's last frame (finished) or at its agent's fall or drift.
    """
    counts = [len(c) for c in data.clips]
    n = max(counts)
    # The training arena's physics; episodes long enough for any clip.
    env_config = dataclasses.replace(config.env, num_envs=n, episode_s=3600.0)
    device = next(policy.parameters()).device
    rows: list[GateRow] = []
    played: list[np.ndarray] = []
    with ArenaEnv(env_config, np.random.default_rng(0), data.bones, str(device)) as env:
        tracker = Tracker(data, config.track, env_config)
        clips = np.stack([np.minimum(np.arange(n), c - 1) for c in counts], 1)
        last = np.array(
            [[data.clips[a][k].num_frames - 1 for a, k in enumerate(row)] for row in clips]
        )
        obs = tracker.reset(
            env, np.arange(n), np.random.default_rng(0), clips=clips, as_filmed=as_filmed
        )
        agent_ids = torch.arange(NUM_AGENTS, device=device).repeat(n)
        alive = np.ones((n, NUM_AGENTS), dtype=bool)
        finished = np.zeros((n, NUM_AGENTS), dtype=bool)
        steps = np.zeros((n, NUM_AGENTS), dtype=int)
        body, root = np.zeros((n, NUM_AGENTS)), np.zeros((n, NUM_AGENTS))
        while alive.any():
            x = torch.as_tensor(obs, dtype=torch.float32, device=device).reshape(2 * n, -1)
            mean, _ = policy.act(x, agent_ids, deterministic=True)
            step = tracker.step(env, mean.reshape(n, NUM_AGENTS, -1).cpu().double().numpy())
            played.append(np.stack([d.qpos.copy() for d in env.datas]))
            steps += alive
            body += np.where(alive, np.nan_to_num(step.body_error, nan=1.0), 0.0)
            root += np.where(alive, np.nan_to_num(step.root_error, nan=1.0), 0.0)
            _, frame = tracker.clip_and_frame()
            at_end = frame >= last
            failed = step.terminal
            finished |= alive & at_end & ~failed
            alive &= ~(at_end | failed)
            obs = step.observation
        model = env.model
    for a in range(NUM_AGENTS):
        for k in range(counts[a]):
            rows.append(
                GateRow(
                    agent=a,
                    clip=data.clips[a][k].name,
                    finished=bool(finished[k, a]),
                    frames=int(steps[k, a]),
                    body_error_cm=float(100 * body[k, a] / steps[k, a]),
                    root_error_cm=float(100 * root[k, a] / steps[k, a]),
                )
            )
    return Played(tuple(rows), np.stack(played), model)


def gate_of(rows: Sequence[GateRow]) -> Gate:
    """The gate's figures over ``rows``."""
    return Gate(
        finished_pct=100 * float(np.mean([r.finished for r in rows])),
        body_error_cm=float(np.mean([r.body_error_cm for r in rows])),
        root_error_cm=float(np.mean([r.root_error_cm for r in rows])),
        rows=tuple(rows),
    )


def track_gate(
    policy: Policy,
    data: TrackingData,
    config: TrainerConfig,
    *,
    agents: Sequence[int] = (0, 1),
) -> Gate:
    """`play_clips` at the agents' slots, judged over the runs of ``agents``."""
    played = play_clips(policy, data, config)
    return gate_of([r for r in played.rows if r.agent in agents])
