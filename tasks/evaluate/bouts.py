"""Evaluation bouts: a pair of controllers in a batch of arenas, recorded.

MAAIP §5.3 evaluates over 32 randomly initialised episodes of 1200 frames; `simulate` runs such
a batch in one `ArenaEnv` (the training environment, its physics, observations, damage and fall
rule), one arena per episode. Every episode starts with both fighters standing still in their
guard (the reference's stance, `standing_like`) where they stand and face in a frame of the
interaction clips drawn with the seed, and runs `frames` policy steps unless a fall (or a
blown-up simulation) ends it; an ended arena is left out of everything after. Training also
starts from mid-motion frames with their velocities (reference state initialisation); an
evaluation from those counted a frame the physics cannot hold (a lifted foot in the air, a
lean) as the policy's fall, even for a fighter standing still in its guard. Each fighter is any
controller (`models.arena.controller`: a trained policy acting on its mean, with no exploration
noise, `tasks.opponent.maaip.TorchPolicy`; the still guard; a tracker playing a clip), reset at
its arena's start, so a seed gives the same bouts every time.

Shape letters: E episodes, T = frames, 2 agents, Q the arena's qpos size (both fighters).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from models.arena.config import EnvConfig
from models.arena.controller import Controller, Seen
from models.arena.env import ArenaEnv
from models.arena.starts import ReferenceMotions
from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import NUM_ACTUATED
from models.humanoid.observations import OBSERVATION_DIM, SELF_BLOCKS, BodyState, block_slices
from models.maaip.losses import heading_reward

_LINEAR = block_slices(SELF_BLOCKS)["body_linear_velocities"]
_ROOT_VELOCITY = slice(_LINEAR.start, _LINEAR.start + 2)  # the pelvis's, on the floor
_RECORDED_STEPS = 16  # steps per episode whose observations are kept (for the ONNX check)


@dataclass(frozen=True)
class HeadingTask:
    """MAAIP §5.4's target heading, as the run trained with it (`train.reward.heading_*`):
    each agent gets a target direction on the floor per episode, seen in its own heading frame,
    and the reward of eq 11 (`models.maaip.losses.heading_reward`) on its root velocity."""

    target_speed: float
    scale: float


@dataclass(frozen=True, eq=False)
class Bouts:
    """What `simulate` recorded.

    Attributes:
        qpos: (E, T + 1, Q) the arena's qpos at the start and after each step; NaN after an
            episode ended (and at the step that blew one up).
        frames: (E,) valid rows of ``qpos`` per episode (steps taken + 1, one fewer when the
            simulation blew up).
        steps: (E,) policy steps each episode ran.
        damage: (E, 2) newtons each agent received, summed over the episode (MAAIP §5.3).
        fell: (E, 2) which agent's fall ended the episode.
        unstable: (E,) episodes ended by a blown-up simulation.
        start_frames: (E,) the reference frames the episodes started from.
        observations: (S, 2, 274) float32 observations the agents acted on, from
            `_RECORDED_STEPS` steps spread over each episode.
        tasks: (S, 2, 2) float32 heading inputs given with them, or None without a heading task.
        task_return: (E, 2) each agent's summed heading reward (eq 11), or None.
        policy_hz: policy steps per simulated second.
    """

    qpos: np.ndarray
    frames: np.ndarray
    steps: np.ndarray
    damage: np.ndarray
    fell: np.ndarray
    unstable: np.ndarray
    start_frames: np.ndarray
    observations: np.ndarray
    tasks: np.ndarray | None
    task_return: np.ndarray | None
    policy_hz: int

    @property
    def episodes(self) -> int:
        return len(self.steps)

    @property
    def minutes(self) -> float:
        """Simulated minutes over all episodes."""
        return float(self.steps.sum()) / self.policy_hz / 60.0

    @property
    def falls_per_min(self) -> float:
        """Episodes ended by a fall (of either fighter) per simulated minute, as training
        counts them."""
        return float(self.fell.any(axis=1).sum()) / self.minutes

    def episode_qpos(self, episode: int) -> np.ndarray:
        """(frames[episode], Q) the episode's valid qpos rows."""
        return self.qpos[episode, : self.frames[episode]]


def mujoco_stepping(env_config: EnvConfig) -> EnvConfig:
    """``env_config`` stepped by MuJoCo: a run trained on MuJoCo Warp is judged in the physics
    its exported opponent spars in (`tasks.opponent.spar`), with the default stepping."""
    if env_config.stepping != "warp":
        return env_config
    return replace(env_config, stepping=EnvConfig().stepping)


def _seen(
    live: np.ndarray, agent: int, bodies: BodyState, obs: np.ndarray, task: np.ndarray | None
) -> Seen:
    """What agent ``agent`` sees in arenas ``live`` of the batch's ``bodies`` (E, 2) and
    observations ``obs`` (E, 2, 274)."""
    return Seen(
        arenas=live,
        slot=agent,
        bodies=bodies[live],
        observation=obs[live, agent],
        partner_observation=obs[live, 1 - agent],
        task=task,
    )


def simulate(
    controllers: tuple[Controller, Controller],
    *,
    reference: ReferenceMotions,
    bones: tuple[BoneLengths, BoneLengths],
    env_config: EnvConfig,
    episodes: int,
    frames: int,
    seed: int,
    heading: HeadingTask | None = None,
) -> Bouts:
    """Run ``episodes`` evaluation episodes of at most ``frames`` steps; see the module docstring.

    Args:
        controllers: agent 0's and agent 1's (e.g. `tasks.opponent.maaip.TorchPolicy`, an
            opponent folder's `controller`, `tasks.opponent.still.StillGuard`), each reset at
            the start; one that keeps something per episode (a tracker) must be a controller
            of its own for each agent (`fresh`).
        reference: interaction frames whose placement the fighters start from, standing in
            their guard (`Demonstrations.reference`).
        bones: both fighters' bones, as trained.
        env_config: the run's environment (rates, fall rule, stepping); its batch size and
            episode length are replaced by ``episodes`` and ``frames``.
        episodes: E, arenas run side by side.
        frames: T, policy steps per episode unless it ends first.
        seed: draws the start frames (and the heading targets).
        heading: the heading task to give the policies (MAAIP §5.4), or None.
    """
    for name, value in (("episodes", episodes), ("frames", frames)):
        if not (isinstance(value, int) and value >= 1):
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    rng = np.random.default_rng(seed)
    starts = rng.integers(reference.num_frames, size=episodes)
    targets = rng.uniform(-math.pi, math.pi, (episodes, 2)) if heading is not None else None
    config = replace(
        mujoco_stepping(env_config),
        num_envs=episodes,
        episode_s=frames / env_config.policy_hz,
        standing_share=1.0,
    )
    stride = max(1, frames // _RECORDED_STEPS)
    with ArenaEnv(config, np.random.default_rng(seed), bones) as env:
        nq = env.model.nq
        qpos = np.full((episodes, frames + 1, nq), np.nan)
        steps = np.zeros(episodes, dtype=np.int64)
        length = np.zeros(episodes, dtype=np.int64)
        damage = np.zeros((episodes, 2))
        fell = np.zeros((episodes, 2), dtype=bool)
        unstable = np.zeros(episodes, dtype=bool)
        task_return = np.zeros((episodes, 2)) if heading is not None else None
        kept_obs, kept_tasks = [], []
        obs = env.reset(np.arange(episodes), reference, frames=starts)
        bodies = env.body_states()
        for i, data in enumerate(env.datas):
            qpos[i, 0] = data.qpos
        length[:] = 1
        alive = np.ones(episodes, dtype=bool)
        for agent, controller in enumerate(controllers):
            controller.reset(_seen(np.arange(episodes), agent, bodies, obs, None))
        for t in range(frames):
            live = np.flatnonzero(alive)
            task = None if targets is None else env.heading_inputs(targets)
            actions = np.zeros((episodes, 2, NUM_ACTUATED))
            for agent, controller in enumerate(controllers):
                given = None if task is None else task[live, agent]
                actions[live, agent] = controller.act(_seen(live, agent, bodies, obs, given))
            if t % stride == 0:
                kept_obs.append(obs[live].astype(np.float32))
                if task is not None:
                    kept_tasks.append(task[live].astype(np.float32))
            result = env.step(actions)
            damage[live] += result.damage[live]
            steps[live] += 1
            if heading is not None:
                after = env.heading_inputs(targets)[live].reshape(-1, 2)
                velocity = result.observation[live][..., _ROOT_VELOCITY].reshape(-1, 2)
                reward = heading_reward(
                    torch.from_numpy(after),
                    torch.from_numpy(velocity),
                    target_speed=heading.target_speed,
                    scale=heading.scale,
                )
                task_return[live] += reward.numpy().reshape(-1, 2)
            for i in live:
                if not result.unstable[i]:
                    qpos[i, t + 1] = env.datas[i].qpos
                    length[i] += 1
            ended = live[result.done[live]]
            fell[ended] = result.fell[ended]
            unstable[ended] = result.unstable[ended]
            alive[ended] = False
            obs, bodies = result.observation, result.body
            if not alive.any():
                break
    observations = np.concatenate(kept_obs) if kept_obs else np.zeros((0, 2, OBSERVATION_DIM))
    return Bouts(
        qpos=qpos,
        frames=length,
        steps=steps,
        damage=damage,
        fell=fell,
        unstable=unstable,
        start_frames=starts,
        observations=observations,
        tasks=np.concatenate(kept_tasks) if kept_tasks else None,
        task_return=task_return,
        policy_hz=env_config.policy_hz,
    )
