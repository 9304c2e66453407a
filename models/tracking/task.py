"""A tracker: each fighter follows reference clips in the arena (`TrainerConfig.objective`
'track', trained by `models.maaip.trainer`).

The method, as physics-based character animation practises it:
- Reference state initialisation (DeepMimic, Peng et al., ACM TOG 37(4), 2018): an
  episode starts at a frame drawn uniformly from every frame (but the last) of every clip,
  with the clip's velocities (or, `TrackConfig.rest_start_share` of them, at rest); the body is
  put exactly where the clip is. With
  `TrackConfig.hard_start_share`, that share of the starts is drawn instead up to
  `hard_start_window_s` before the frames where recent episodes ended terminally, in
  proportion to how many did (hard-negative mining, as PHC, Luo et al. 2023, samples the
  motions it fails; here by frame, so that a clip lost in its second half starts there).
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
(agent 1), heading kept, and they never meet; or, for `TrackConfig.together_share` of the
starts, both agents start at one frame of one piece of footage (or one matched stream) where it
has them, and meet as the fighters did. An arena's episode ends when either agent's does; the
other agent's ending is then a time-out for it (bootstrapped), not a termination.

In training, a Tracker given a generator for them pushes its fighters now and then
(`TrackConfig.push_every_s`, `models.arena.pushes`), as DReCon did, so that it learns to recover;
and one told to anchor (`TrackConfig.anchor_m`) moves a reference that strays from its body back
under it, as the matched opponent's motion is moved in a bout.

Which reference frame comes next is the task's frame source (`FrameSource`): by default the
clip's next frame (`NextFrame`), so that the tracker plays each clip through; another source
(a motion matcher, say) may pick the next frame elsewhere in the library. The errors
(`body_error`, `root_error`) and the reward are `models.tracking.reward`'s.

Shape letters: F frames of all clips, N environments, n of them, 2 agents, B bodies (15).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from models.arena.config import EnvConfig
from models.arena.env import ArenaEnv, StepResult, to_host
from models.arena.mjcf import NUM_AGENTS
from models.arena.pushes import random_pushes
from models.humanoid.kinematics import NQ, NUM_ACTUATED, NV, heading_frame_of_matrix
from models.humanoid.observations import SELF_DIM, BodyState, self_observation, stacked
from models.tracking.clips import ClipLibrary, TrackingData, clip_library
from models.tracking.config import TrackConfig
from models.tracking.reward import (
    REWARD_TERMS,
    body_error,
    centre_of_mass,
    deepmimic_reward,
    root_error,
)

TRACK_INPUT_DIM = SELF_DIM + 5  # the next frame's o^self, its pelvis (3) and heading (cos, sin)
TRACK_OBSERVATION_DIM = SELF_DIM + TRACK_INPUT_DIM  # 451


def tracking_input(sim: BodyState, ref: BodyState, ref_observation: np.ndarray) -> np.ndarray:
    """(..., 228) what the policy is told of the frame to reach: its o^self (``ref_observation``
    (..., 223)), then the reference pelvis relative to the agent's in the agent's heading frame
    (3) and the cosine and sine of the reference heading's yaw relative to the agent's."""
    mine = heading_frame_of_matrix(sim.rot[..., 0, :, :])
    theirs = heading_frame_of_matrix(ref.rot[..., 0, :, :])
    offset = ((ref.pos[..., 0, :] - sim.pos[..., 0, :])[..., None, :] @ mine)[..., 0, :]
    turn = mine.swapaxes(-1, -2) @ theirs
    return np.concatenate([ref_observation, offset, turn[..., 0, 0:1], turn[..., 1, 0:1]], axis=-1)


def training_pushes(
    env: ArenaEnv, config: TrackConfig, rng: np.random.Generator | None
) -> np.ndarray | None:
    """This step's random pushes on the fighters of every arena of ``env``
    (`TrackConfig.push_every_s`, `models.arena.pushes`), or None without a generator."""
    if rng is None:
        return None
    step_s = 1.0 / env.config.policy_hz
    return random_pushes(
        rng,
        np.stack([agent.body_ids for agent in env.index.agents]),
        num_envs=env.num_envs,
        nbody=env.model.nbody,
        chance=min(1.0, step_s / config.push_every_s),
        mass_kg=(config.push_mass_min_kg, config.push_mass_max_kg),
        speed_mps=config.push_speed_mps,
        step_s=step_s,
    )


def pushed_agents(env: ArenaEnv, pushes: np.ndarray | None) -> np.ndarray:
    """(N, 2) which agents of ``env``'s arenas ``pushes`` (`training_pushes`) hit."""
    if pushes is None:
        return np.zeros((env.num_envs, NUM_AGENTS), dtype=bool)
    return np.stack([pushes[:, agent.body_ids].any(axis=(1, 2)) for agent in env.index.agents], 1)


class FrameSource(Protocol):
    """Which reference frame each agent follows next. The tracker asks wherever it needs the
    next frame (the observation, the PD targets, the step), so the answer must follow from the
    current frames alone."""

    def next(self, libraries: Sequence[ClipLibrary], flat: np.ndarray) -> np.ndarray:
        """(n, 2) the flat index, in agent a's library ``libraries[a]``, of each agent's next
        reference frame, given its current one ``flat`` (n, 2)."""
        ...


@dataclass(frozen=True)
class NextFrame:
    """The default frame source: each clip's next frame, held at its last."""

    def next(self, libraries: Sequence[ClipLibrary], flat: np.ndarray) -> np.ndarray:
        return np.stack([f.next(flat[:, a]) for a, f in enumerate(libraries)], 1)


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
        pushed: (N, 2) which agents were pushed in the step (`TrackConfig.push_every_s`).
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
    pushed: np.ndarray

    @property
    def done(self) -> np.ndarray:
        return self.terminated | self.truncated


def check_rate(data: TrackingData, env: EnvConfig) -> None:
    """ValueError unless ``data``'s clips are at the policy's rate, a frame a step."""
    if data.fps != env.policy_hz:
        raise ValueError(
            f"the clips of {data.key!r} are at {data.fps} fps, the policy steps at "
            f"{env.policy_hz} Hz: retarget them at the policy's rate"
        )


def check_corrections(env: ArenaEnv, corrections: np.ndarray) -> None:
    """ValueError unless ``corrections`` are (N, 2, 28), one per agent of each arena."""
    if corrections.shape != (env.num_envs, NUM_AGENTS, NUM_ACTUATED):
        raise ValueError(
            f"corrections must have shape ({env.num_envs}, 2, {NUM_ACTUATED}), "
            f"got {corrections.shape}"
        )


def judged(
    result: StepResult,
    sim: BodyState,
    ref: BodyState,
    sim_com: np.ndarray,
    ref_com: np.ndarray,
    observation: np.ndarray,
    *,
    config: TrackConfig,
    pushed: np.ndarray,
    ended: np.ndarray | None = None,
) -> TrackStep:
    """A tracking step as training reads it: DeepMimic's reward and the errors of bodies ``sim``
    (N, 2) against the frames ``ref`` (N, 2) just reached (their centres of mass ``sim_com`` and
    ``ref_com`` (N, 2, 3)); a fall, a drift past `TrackConfig.root_limit_m` or a blown-up
    simulation ends an episode terminally, the arena's time limit or ``ended`` (N,) as a
    time-out. An unstable environment's reward, terms and ``observation`` (N, 2, 451, zeroed
    in place) are 0 and its errors NaN."""
    with np.errstate(all="ignore"):  # an unstable environment's numbers are not finite
        terms = deepmimic_reward(sim, ref, sim_com, ref_com, config=config)
        body, root = body_error(sim, ref), root_error(sim, ref)
        drift = root > config.root_limit_m
    stable = ~result.unstable
    terminal = result.fell | drift | result.unstable[:, None]
    terminated = terminal.any(1)
    over = result.truncated if ended is None else ended | result.truncated
    columns = np.stack([terms[k] for k in REWARD_TERMS], -1)
    columns[~stable] = 0.0
    observation[~stable] = 0.0
    return TrackStep(
        observation=observation,
        terminated=terminated,
        truncated=over & ~terminated,
        terminal=terminal,
        fell=result.fell,
        damage=to_host(result.damage),
        unstable=result.unstable,
        reward=np.where(stable[:, None], terms["total"], 0.0),
        terms=columns,
        body_error=np.where(stable[:, None], body, np.nan),
        root_error=np.where(stable[:, None], root, np.nan),
        pushed=pushed,
    )


class Tracker:
    """Tracking episodes of N arenas, both agents: which clip and frame each agent is at and
    where its clip was put (module docstring); ``source`` says which frame comes next
    (`NextFrame` unless given); ``pushes`` is the generator of the random pushes of training
    (`TrackConfig.push_every_s`; None: no pushes, as the gate and the replays play); with
    ``anchored`` the references are moved back under bodies they strayed from
    (`TrackConfig.anchor_m`; training only, too). `state` and `load_state` checkpoint it."""

    def __init__(
        self,
        data: TrackingData,
        config: TrackConfig,
        env: EnvConfig,
        *,
        source: FrameSource | None = None,
        pushes: np.random.Generator | None = None,
        anchored: bool = False,
    ):
        check_rate(data, env)
        num_envs = env.num_envs
        self.data, self.config = data, config
        self.libraries = tuple(clip_library(clips, fps=data.fps) for clips in data.clips)
        if config.together_share > 0 and not self._paired():
            raise ValueError(
                f"train.track.together_share: the fighters' clips of {data.key!r} do not pair "
                "up clip for clip (equal lengths), so they cannot start together"
            )
        self.pushes = pushes if config.push_every_s > 0 else None
        self.anchor_m = config.anchor_m if anchored else 0.0
        self.source: FrameSource = NextFrame() if source is None else source
        self.flat = np.zeros((num_envs, NUM_AGENTS), dtype=int)  # index into `libraries`
        self.offset = np.zeros((num_envs, NUM_AGENTS, 3))  # added to the clip's positions
        self.slots = np.array(
            [[0.0, -config.separation_m / 2, 0.0], [0, config.separation_m / 2, 0]]
        )
        # Each agent's recent terminal endings by the frame it was on (decaying), which
        # weight the hard starts (`TrackConfig.hard_start_share`).
        self.failures = [np.zeros(len(f.clip.qpos)) for f in self.libraries]

    def _paired(self) -> bool:
        """Whether clip k of agent 0 and of agent 1 are one piece of footage (equal lengths)."""
        return np.array_equal(self.libraries[0].last, self.libraries[1].last)

    def state(self) -> dict:
        return {
            "flat": self.flat.copy(),
            "offset": self.offset.copy(),
            "failures": [f.copy() for f in self.failures],
            "pushes": None if self.pushes is None else self.pushes.bit_generator.state,
        }

    def load_state(self, state: dict) -> None:
        self.flat[:] = state["flat"]
        self.offset[:] = state["offset"]
        for mine, saved in zip(self.failures, state.get("failures", ()), strict=False):
            mine[:] = saved
        if self.pushes is not None and state.get("pushes") is not None:
            self.pushes.bit_generator.state = state["pushes"]

    def start_weights(self, agent: int) -> np.ndarray:
        """(len(startable),) the probability of each of agent ``agent``'s startable frames as an
        episode start: uniform, mixed with `hard_start_share` of the frames up to
        `hard_start_window_s` before its recent failures (module docstring)."""
        f = self.libraries[agent]
        uniform = np.full(len(f.startable), 1.0 / len(f.startable))
        share = self.config.hard_start_share
        if share == 0:
            return uniform
        # Failures within the window after each frame, in its own clip: prefix sums.
        window = max(1, round(self.config.hard_start_window_s * f.fps))
        before = np.concatenate([[0.0], np.cumsum(self.failures[agent])])
        frames = f.startable
        clip_last = f.last[np.searchsorted(f.last, frames)]
        ahead = before[np.minimum(frames + window, clip_last) + 1] - before[frames]
        if ahead.sum() <= 0:
            return uniform
        return (1 - share) * uniform + share * ahead / ahead.sum()

    def clip_and_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) each agent's clip index and frame in it."""
        found = [f.locate(self.flat[:, a]) for a, f in enumerate(self.libraries)]
        return np.stack([c for c, _ in found], 1), np.stack([k for _, k in found], 1)

    def reference(self, flat: np.ndarray, ids: np.ndarray | slice = slice(None)) -> BodyState:
        """(n, 2) the reference frames ``flat`` (n, 2) of environments ``ids``, where placed."""
        both = stacked([f.clip.states[flat[:, a]] for a, f in enumerate(self.libraries)])
        return replace(both, pos=both.pos + self.offset[ids][:, :, None, :])

    def next_frames(self, ids: np.ndarray | slice = slice(None)) -> np.ndarray:
        """(n, 2) the flat index of each agent's next frame in environments ``ids``, as the
        frame source says."""
        return self.source.next(self.libraries, self.flat[ids])

    def observation(
        self,
        sim: BodyState,
        ids: np.ndarray | slice = slice(None),
        *,
        own: np.ndarray | None = None,
    ) -> np.ndarray:
        """(n, 2, 451) o^self of ``sim`` (n, 2) (``own`` where the arena computed it already)
        and the next reference frame (`tracking_input`)."""
        nxt = self.next_frames(ids)
        ref_obs = np.stack([f.clip.observation[nxt[:, a]] for a, f in enumerate(self.libraries)], 1)
        given = tracking_input(sim, self.reference(nxt, ids), ref_obs)
        return np.concatenate([self_observation(sim) if own is None else own, given], -1)

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
        the same frame of it and where the footage has them. Drawn starts are made so, together,
        with `TrackConfig.together_share`. Returns their observations (n, 2, 451)."""
        ids = np.asarray(ids, dtype=int)
        qpos = np.empty((len(ids), NUM_AGENTS, NQ))
        qvel = np.empty((len(ids), NUM_AGENTS, NV))
        if as_filmed and not self._paired():
            raise ValueError("as_filmed: the agents' clips must pair up, clip k of equal length")
        together = np.full(len(ids), as_filmed)
        if self.config.together_share > 0 and clips is None and not as_filmed:
            together = rng.random(len(ids)) < self.config.together_share
        for a, f in enumerate(self.libraries):
            if clips is not None:
                flat = f.index(np.asarray(clips)[:, a], 0)
            elif as_filmed and a == 1:
                flat = self.flat[ids, 0]  # agent 0's frame: the same step of the same footage
            elif self.config.hard_start_share > 0:
                flat = rng.choice(f.startable, size=len(ids), p=self.start_weights(a))
            else:
                flat = f.startable[rng.integers(len(f.startable), size=len(ids))]
            if a == 1 and clips is None:
                flat = np.where(together, self.flat[ids, 0], flat)
            self.flat[ids, a] = flat
            offset = self.slots[a] - f.clip.qpos[flat, :3] * [1, 1, 0]
            offset[together] = 0.0
            self.offset[ids, a] = offset
            qpos[:, a] = f.clip.qpos[flat]
            qpos[:, a, :3] += self.offset[ids, a]
            qvel[:, a] = f.clip.qvel[flat]
        if self.config.rest_start_share > 0 and clips is None:
            qvel[rng.random(len(ids)) < self.config.rest_start_share] = 0.0
        env.set_states(ids, qpos, qvel)
        return self.observation(env.body_states(ids), ids)

    def actions(self, corrections: np.ndarray) -> np.ndarray:
        """(N, 2, 28) the arena's actions: each agent's next reference frame (the PD targets
        that hold it) plus its ``corrections`` (N, 2, 28) (DReCon)."""
        nxt = self.next_frames()
        held = np.stack([f.clip.actions[nxt[:, a]] for a, f in enumerate(self.libraries)], 1)
        return held + corrections

    def step(self, env: ArenaEnv, corrections: np.ndarray) -> TrackStep:
        """One policy step of every environment: PD targets from `actions`, then every agent
        on its next frame, rewarded and checked against it."""
        check_corrections(env, corrections)
        pushes = training_pushes(env, self.config, self.pushes)
        result: StepResult = env.step(self.actions(corrections), pushes=pushes, opponent=False)
        self.flat = self.next_frames()
        # The rewards are computed on the host (with "warp" the bodies come down from the device).
        body = result.body
        sim = BodyState(*(to_host(x) for x in (body.pos, body.rot, body.lin_vel, body.ang_vel)))
        ref = self.reference(self.flat)
        if self.anchor_m > 0:
            back = sim.pos[:, :, 0] - ref.pos[:, :, 0]
            back[..., 2] = 0.0
            with np.errstate(invalid="ignore"):  # an unstable environment's pelvis is not finite
                far = np.linalg.norm(back, axis=-1) > self.anchor_m
            self.offset[far] += back[far]
            ref.pos[far] += back[far][:, None]  # the reference as laid again, not made twice
        sim_com = np.stack(
            [
                centre_of_mass(sim[:, a], f.clip.body_mass, f.clip.body_com)
                for a, f in enumerate(self.libraries)
            ],
            1,
        )
        ref_com = np.stack([f.clip.com[self.flat[:, a]] for a, f in enumerate(self.libraries)], 1)
        with np.errstate(all="ignore"):  # an unstable environment's numbers are not finite
            observation = self.observation(sim, own=to_host(result.self_observation))
        ended = np.stack([f.at_end(self.flat[:, a]) for a, f in enumerate(self.libraries)], 1)
        scored = judged(
            result,
            sim,
            ref,
            sim_com,
            ref_com + self.offset,
            observation,
            config=self.config,
            pushed=pushed_agents(env, pushes),
            ended=ended.any(1),
        )
        if self.config.hard_start_share > 0:
            keep = np.exp(-1.0 / self.config.hard_start_memory_steps)
            for a, failures in enumerate(self.failures):
                failures *= keep
                np.add.at(failures, self.flat[scored.terminal[:, a], a], 1.0)
        return scored
