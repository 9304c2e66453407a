"""MAAIP from the tracker: a trained tracker distilled into MAAIP's policy (`DistillConfig`).

The tracker sees the next reference frame; MAAIP's policy sees only the two fighters (o^self,
o^opp). Distillation fits MAAIP's policy mean to the tracker's actions on the states where it
acts, so that MAAIP's fine-tuning starts from a policy that already moves like the clips
instead of from one that holds a guard:

- Both fighters of every arena play one piece of footage together, where it was filmed
  (`Tracker.reset(as_filmed=True)`): agent 0 the adversary's clip, agent 1 the opponent's, from
  a frame drawn from every frame of the clips, with their velocities; so o^opp is the other
  fighter as the footage has him.
- Round 0 acts on the tracker's actions plus Gaussian noise (DART, Laskey et al. 2017); every
  later round acts on the student's own mean (DAgger, Ross et al. 2011), so it learns to recover
  from its own mistakes; every state visited is labelled with the tracker's action there (the
  reference frame plus its correction, PD targets in MAAIP's action space) and the student is
  refitted on all labels so far (mean squared error, Adam).
- An episode ends as the tracker's does: a fall, the pelvis `TrackConfig.root_limit_m` from the
  reference's, or the clip's end.

Each round's figures: the student's fit (mean squared error, rad^2) and the mean length (s) of
the episodes that ended in the round, acted by the student from round 1 on: how long the
distilled policy follows the footage on its own.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from models.arena.env import ArenaEnv
from models.humanoid.kinematics import NUM_ACTUATED
from models.maaip.config import NUM_AGENTS, TrainerConfig
from models.maaip.networks import Policy
from models.tracking.clips import TrackingData
from models.tracking.task import Tracker


def _fit(
    student: Policy,
    obs: torch.Tensor,
    agents: torch.Tensor,
    labels: torch.Tensor,
    config: TrainerConfig,
    generator: torch.Generator,
) -> float:
    """Fit ``student``'s mean to ``labels``; the last epoch's mean squared error."""
    settings = config.distill
    optimiser = torch.optim.Adam(student.net.parameters(), lr=settings.learning_rate)
    n = len(obs)
    loss_sum = 0.0
    for _ in range(settings.epochs):
        order = torch.randperm(n, generator=generator)
        loss_sum = 0.0
        for start in range(0, n, settings.minibatch_size):
            rows = order[start : start + settings.minibatch_size]
            loss = (student(obs[rows], agents[rows]) - labels[rows]).square().mean()
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            loss_sum += float(loss.detach()) * len(rows)
    return loss_sum / n


def distill(
    student: Policy,
    teacher: Policy,
    data: TrackingData,
    config: TrainerConfig,
    *,
    generator: torch.Generator,
    rng: np.random.Generator,
) -> list[dict[str, float]]:
    """Distil tracker ``teacher`` into MAAIP policy ``student`` (in place) on ``data``, the two
    fighters' footage clips paired clip by clip (module docstring); each round's figures."""
    settings = config.distill
    n = config.env.num_envs
    env_config = dataclasses.replace(config.env, episode_s=3600.0)  # the clips end episodes
    agents = torch.arange(NUM_AGENTS).repeat(n)
    every = np.arange(n)
    seen_obs: list[torch.Tensor] = []
    seen_labels: list[torch.Tensor] = []
    rounds = []
    with ArenaEnv(env_config, rng, data.bones) as env:
        tracker = Tracker(data, config.track, env_config)
        for round_ in range(settings.rounds):
            told = tracker.reset(env, every, rng, as_filmed=True)
            obs = env.observe()
            age = np.zeros(n, dtype=int)
            lengths: list[int] = []
            for _ in range(settings.steps):
                held = tracker.actions(np.zeros((n, NUM_AGENTS, NUM_ACTUATED)))
                x = torch.as_tensor(told, dtype=torch.float32).reshape(2 * n, -1)
                correction, _ = teacher.act(x, agents, deterministic=True)
                label = held + correction.reshape(n, NUM_AGENTS, -1).double().numpy()
                mine = torch.as_tensor(obs, dtype=torch.float32).reshape(2 * n, -1)
                seen_obs.append(mine)
                seen_labels.append(torch.as_tensor(label, dtype=torch.float32).reshape(2 * n, -1))
                if round_ == 0:
                    acted = label + rng.normal(0.0, settings.noise, label.shape)
                else:
                    mean, _ = student.act(mine, agents, deterministic=True)
                    acted = mean.reshape(n, NUM_AGENTS, -1).double().numpy()
                step = tracker.step(env, acted - held)
                age += 1
                told, obs = step.observation, env.observe()
                done = np.flatnonzero(step.done)
                if done.size:
                    lengths += age[done].tolist()
                    age[done] = 0
                    told = told.copy()
                    told[done] = tracker.reset(env, done, rng, as_filmed=True)
                    obs[done] = env.observe(done)
            new = torch.cat(seen_obs[-settings.steps :])
            student.norm.update(new)
            loss = _fit(
                student,
                torch.cat(seen_obs),
                agents.repeat(len(seen_obs)),
                torch.cat(seen_labels),
                config,
                generator,
            )
            hz = config.env.policy_hz
            rounds.append(
                {
                    "round": float(round_),
                    "loss": loss,
                    "episode_s": float(np.mean(lengths)) / hz if lengths else settings.steps / hz,
                    "samples": float(sum(len(o) for o in seen_obs)),
                }
            )
    return rounds
