"""What differs between the trainer's objectives (`TrainerConfig.objective`), each one object
the one training loop (`models.maaip.trainer.Trainer`) is given:

- 'maaip' (`MotionPriors`): MAAIP's motion prior and one interaction prior per agent (§4.3):
  the policy acts on the arena directly; after each collection the rewards come from the
  discriminators (eqs 4-6, with a control reward if asked, eqs 9-11), whose replay buffers take
  the policy's transitions and who then train (Algorithm 1, 17-20).
- 'track' (`Tracking`): a tracker (`models.tracking`): the arena's actions are each agent's
  next reference frame plus the policy's correction, the reward is DeepMimic's, computed as the
  steps are collected; no discriminators.

An objective supplies its networks (`networks`), the size of what its policy sees
(`observation_dim`), episode starts (`reset`), steps (`step`: the policy's actions to the
arena, and what it records of each step), the rewards and its own learning (`learn`) and the
state it adds to a checkpoint (`state`, `load_state`). `objective_kind` is the one place an
objective is chosen by name.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import torch
from torch import Tensor

from models.arena.env import ArenaEnv
from models.humanoid.boxer import BoneLengths
from models.humanoid.observations import OBSERVATION_DIM, SELF_BLOCKS, SELF_DIM, block_slices
from models.maaip.config import TrainerConfig
from models.maaip.demonstrations import Demonstrations
from models.maaip.losses import (
    combine_rewards,
    damage_reward,
    discriminator_loss,
    heading_reward,
    reward_weights,
    style_reward_from_config,
)
from models.maaip.networks import (
    CentralValue,
    Discriminator,
    Networks,
    Policy,
    ReplayBuffer,
    action_stds,
    make_networks,
)
from models.tracking.bouts import BoutTracker
from models.tracking.clips import TrackingData
from models.tracking.reward import REWARD_TERMS
from models.tracking.task import TRACK_OBSERVATION_DIM, Tracker

HELD_OUT_ROWS = 4096
_LINEAR = block_slices(SELF_BLOCKS)["body_linear_velocities"]
_ROOT_VELOCITY = slice(_LINEAR.start, _LINEAR.start + 3)

# Runs ``fn(*args)`` and records its wall-clock time under ``name`` in the iteration's metrics.
Timed = Callable[..., Any]


@dataclass
class Rollout:
    """T steps of N environments, both agents, as float32 tensors (T, N, 2, ...)."""

    obs: Tensor
    next_obs: Tensor
    actions: Tensor
    log_probs: Tensor
    damage: Tensor  # received by each agent
    terminated: Tensor  # (T, N)
    truncated: Tensor  # (T, N)
    fell: Tensor  # (T, N, 2)
    unstable: Tensor  # (T, N) the simulation blew up (terminal, not a fall)
    task: Tensor | None = None  # (T, N, 2, 2) heading targets the actions were chosen for
    next_task: Tensor | None = None  # the same targets seen from the next state
    # Recorded by the tracker (`Tracking.step`): the reward (T, N, 2) and its terms (T, N, 2, 4),
    # body and root errors in metres (T, N, 2, 2), and which agents' own episodes ended
    # terminally (T, N, 2): the other agent of an environment that ended times out.
    reward: Tensor | None = None
    reward_terms: Tensor | None = None
    errors: Tensor | None = None
    terminal: Tensor | None = None


class Stepped(Protocol):
    """What the loop reads of one step of every environment (`StepResult`, `TrackStep`)."""

    @property
    def observation(self) -> np.ndarray | Tensor: ...
    @property
    def damage(self) -> np.ndarray | Tensor: ...
    @property
    def terminated(self) -> np.ndarray: ...
    @property
    def truncated(self) -> np.ndarray: ...
    @property
    def fell(self) -> np.ndarray: ...
    @property
    def unstable(self) -> np.ndarray: ...
    @property
    def done(self) -> np.ndarray: ...


@dataclass(frozen=True)
class Learned:
    """An objective's `learn`: the rollout's rewards and what its own learning reports.

    Attributes:
        rewards: each reward term (T, N, 2), with their sum as "total", which PPO maximises.
        stats: the objective's own updates' figures (the discriminators'), before PPO's.
        metrics: its own figures of the rollout, last among the iteration's metrics.
    """

    rewards: dict[str, Tensor]
    stats: dict[str, float]
    metrics: dict[str, float]


class Objective(Protocol):
    """One objective of a run, built by its kind (`ObjectiveKind`) for the run's config and
    data. ``key`` and ``bones`` name the data and its two humanoids; ``discriminators`` are
    the networks it trains beside the policy and value (checkpointed with them; none for a
    tracker)."""

    key: str
    bones: tuple[BoneLengths, ...]
    discriminators: tuple[Discriminator, ...]

    def reset(
        self, env: ArenaEnv, ids: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray | Tensor:
        """Start environments ``ids`` (n,), drawing from ``rng``; their observations."""
        ...

    def step(self, env: ArenaEnv, actions: Tensor) -> tuple[Stepped, dict[str, np.ndarray]]:
        """Step every environment on the policy's ``actions`` (N, 2, 28); the step, and what
        the rollout records of it beyond what every objective does (`Rollout` fields)."""
        ...

    def learn(self, rollout: Rollout, iteration: int, timed: Timed) -> Learned:
        """The rollout's rewards, after the objective's own updates."""
        ...

    def state(self) -> dict:
        """Its part of a checkpoint: the `TrainState` fields d_optimisers, buffers, tracker."""
        ...

    def load_state(self, state: Mapping[str, Any]) -> None:
        """Continue from a `TrainState`'s fields (``vars(state)``)."""
        ...


class ObjectiveKind(Protocol):
    """An objective's class: the data it trains on, its policy's observation size, its
    networks, and itself for a run."""

    data_type: type
    observation_dim: int

    def networks(
        self, config: TrainerConfig, data: Any, generator: torch.Generator
    ) -> Networks: ...

    def __call__(
        self,
        config: TrainerConfig,
        data: Any,
        nets: Networks,
        *,
        generator: torch.Generator,
        device: torch.device,
    ) -> Objective: ...


# --------------------------------------------------------------------------
# MAAIP: motion and interaction priors
# --------------------------------------------------------------------------


class MotionPriors:
    """MAAIP's objective (module docstring) on ``data``'s demonstrations: each discriminator
    with its optimiser and replay buffer, the demonstrations it learns from and, to judge it,
    the held-out ones (the validation split)."""

    data_type = Demonstrations
    observation_dim = OBSERVATION_DIM

    @staticmethod
    def networks(
        config: TrainerConfig, data: Demonstrations, generator: torch.Generator
    ) -> Networks:
        """MAAIP's networks, the policy starting from the dataset's guard."""
        return make_networks(config, generator=generator, stance=data.reference.stance)

    def __init__(
        self,
        config: TrainerConfig,
        data: Demonstrations,
        nets: Networks,
        *,
        generator: torch.Generator,
        device: torch.device,
    ):
        disc = config.discriminator
        self.config, self.demos, self.nets = config, data, nets
        self.generator, self.device = generator, device
        self.key, self.bones = data.dataset_key, data.bones
        self.discriminators: tuple[Discriminator, ...] = (nets.motion, *nets.interaction)
        for d in self.discriminators:
            d.to(device)
        self.d_optimisers = [
            torch.optim.Adam(d.parameters(), lr=disc.learning_rate, fused=True)
            for d in self.discriminators
        ]
        self.buffers = [
            ReplayBuffer(disc.replay_size, d.input_dim, device=device) for d in self.discriminators
        ]
        self.real = [torch.from_numpy(x).to(device) for x in (data.motion, *data.interaction)]
        # Held-out demonstrations (the validation split), to judge each discriminator on what it
        # never learned from; the first HELD_OUT_ROWS of each, so the check costs little.
        self.held_out = [torch.from_numpy(x[:HELD_OUT_ROWS]).to(device) for x in data.held_out]

    def reset(
        self, env: ArenaEnv, ids: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray | Tensor:
        """The demonstrations' reference state initialisation (`ArenaEnv.reset`)."""
        return env.reset(ids, self.demos.reference)

    def step(self, env: ArenaEnv, actions: Tensor) -> tuple[Stepped, dict[str, np.ndarray]]:
        # To the arena as they are: the host's, or Warp's device, takes them.
        return env.step(actions), {}

    def learn(self, rollout: Rollout, iteration: int, timed: Timed) -> Learned:
        """Algorithm 1's steps 2-3: the rewards, then the discriminators' updates."""
        inputs = self.discriminator_inputs(rollout)
        terms = timed("rewards_s", self.rewards, rollout, inputs, iteration)
        d_stats = timed("discriminators_s", self.update_discriminators, inputs)
        w_m, w_i, w_c = reward_weights(self.config.reward, iteration)
        weights = {"w_motion": w_m, "w_interaction": w_i, "w_control": w_c}
        return Learned(terms, d_stats, weights)

    def discriminator_inputs(self, r: Rollout) -> list[Tensor]:
        """The rollout's transitions as each discriminator takes them: D^M's
        [o^self_t, o^self_t+1] of both agents (T*N*2, 446), then D^I_i's [o_t, o^self_t+1] of
        agent i (T*N, 497)."""
        next_self = r.next_obs[..., :SELF_DIM]
        inputs = [torch.cat([r.obs[..., :SELF_DIM], next_self], -1).reshape(-1, 2 * SELF_DIM)]
        for agent in range(2):
            pair = torch.cat([r.obs[:, :, agent], next_self[:, :, agent]], -1)
            inputs.append(pair.reshape(-1, pair.shape[-1]))
        return inputs

    def rewards(self, r: Rollout, inputs: list[Tensor], iteration: int) -> dict[str, Tensor]:
        """Each reward term (T, N, 2) and their scheduled sum (eq 4); ``inputs`` are
        `discriminator_inputs`."""
        disc = self.config.discriminator
        with torch.no_grad():
            motion = style_reward_from_config(self.nets.motion(inputs[0]), disc)
            interaction = torch.stack(
                [
                    style_reward_from_config(d(x), disc).reshape(r.log_probs.shape[:2])
                    for d, x in zip(self.nets.interaction, inputs[1:], strict=True)
                ],
                dim=-1,
            )
        terms = {"motion": motion.reshape(r.log_probs.shape), "interaction": interaction}
        task = self.config.reward.control_task
        control = None
        if task in ("damage_min", "damage_max"):
            # eq 9 on the damage an agent receives, eq 10 on what it deals (the other's).
            force = r.damage if task == "damage_min" else r.damage.flip(-1)
            control = damage_reward(
                force, scale=self.config.reward.damage_scale, maximize=task == "damage_max"
            )
            terms["control"] = control
        elif task == "heading":
            # The root's velocity and the target, both in the agent's heading frame after the
            # step (o^self's first velocity row is the pelvis's).
            velocity = r.next_obs[..., _ROOT_VELOCITY]
            control = heading_reward(
                r.next_task.reshape(-1, 2),
                velocity[..., :2].reshape(-1, 2),
                target_speed=self.config.reward.heading_speed,
                scale=self.config.reward.heading_scale,
            ).reshape(r.log_probs.shape)
            terms["control"] = control
        terms["total"] = combine_rewards(
            terms["motion"],
            terms["interaction"],
            control,
            config=self.config.reward,
            iteration=iteration,
        )
        return terms

    def update_discriminators(self, fakes: list[Tensor]) -> dict[str, float]:
        """Replay the policy's transitions (`discriminator_inputs`) and train D^M and each D^I
        (Algorithm 1, 17-20)."""
        disc = self.config.discriminator
        stats: dict[str, float] = {}
        names = ("motion", "interaction0", "interaction1")
        for index, (name, d, opt, buffer, real, fake) in enumerate(
            zip(
                names,
                self.discriminators,
                self.d_optimisers,
                self.buffers,
                self.real,
                fakes,
                strict=True,
            )
        ):
            buffer.add(fake)
            pick = torch.randint(len(real), (len(fake),), generator=self.generator)
            d.norm.update(torch.cat([real[pick], fake]))
            for _ in range(disc.updates_per_iteration):
                k = disc.samples_per_update
                real_k = real[torch.randint(len(real), (k,), generator=self.generator)]
                loss, s = discriminator_loss(
                    d,
                    real_k,
                    buffer.sample(k, generator=self.generator),
                    config=disc,
                    generator=self.generator,
                )
                opt.zero_grad()
                loss.backward()
                opt.step()
            stats[f"{name}_accuracy_real"] = s.accuracy_real
            stats[f"{name}_accuracy_fake"] = s.accuracy_fake
            stats[f"{name}_gradient_penalty"] = s.gradient_penalty
            stats.update(self._judged(name, d, fake, index))
        return stats

    def _judged(self, name: str, d, fresh: Tensor, index: int) -> dict[str, float]:
        """Discriminator ``d`` after its update, on what it did not train on: this iteration's
        fresh policy samples (the updates drew theirs from the replay) and the held-out
        demonstrations, where there are any. Accuracy as in training (logit < 0 for the
        policy's, > 0 for the demonstrations'), and the mean D = sigmoid(logit), the
        probability it gives of "real". No random number is drawn: a run's course is the same
        with or without these."""
        with torch.no_grad():
            logits = d(fresh)
            out = {
                f"{name}_fresh_accuracy_fake": (logits < 0).float().mean().item(),
                f"{name}_fresh_d": torch.sigmoid(logits).mean().item(),
            }
            held = self.held_out[index] if index < len(self.held_out) else None
            if held is not None and len(held):
                logits = d(held)
                out[f"{name}_held_out_accuracy_real"] = (logits > 0).float().mean().item()
                out[f"{name}_held_out_d"] = torch.sigmoid(logits).mean().item()
        return out

    def state(self) -> dict:
        return {
            "d_optimisers": [o.state_dict() for o in self.d_optimisers],
            "buffers": [b.state() for b in self.buffers],
            "tracker": None,
        }

    def load_state(self, state: Mapping[str, Any]) -> None:
        for o, s in zip(self.d_optimisers, state["d_optimisers"], strict=True):
            o.load_state_dict(s)
        for b, s in zip(self.buffers, state["buffers"], strict=True):
            b.load_state(s)


# --------------------------------------------------------------------------
# The tracker
# --------------------------------------------------------------------------


def tracking_networks(
    config: TrainerConfig, *, generator: torch.Generator
) -> tuple[Policy, CentralValue]:
    """The tracker's policy and value: MAAIP's, with the tracker's observation
    (TRACK_OBSERVATION_DIM), a mean of zero correction (no guard offset), and a value that reads
    the other agent's observation only with `TrackConfig.value_sees_partner`."""
    hidden, clip = config.network.hidden_sizes, config.network.observation_clip
    policy = Policy(
        hidden=hidden,
        action_std=action_stds(config),
        obs_dim=TRACK_OBSERVATION_DIM,
        observation_clip=clip,
        generator=generator,
    )
    value = CentralValue(
        hidden=hidden,
        obs_dim=TRACK_OBSERVATION_DIM,
        observation_clip=clip,
        sees_other=config.track.value_sees_partner,
        generator=generator,
    )
    return policy, value


class Tracking:
    """The tracker's objective (module docstring): ``data``'s clips tracked by a `Tracker`."""

    data_type = TrackingData
    observation_dim = TRACK_OBSERVATION_DIM

    @staticmethod
    def networks(config: TrainerConfig, data: TrackingData, generator: torch.Generator) -> Networks:
        """The tracker's policy and value (`tracking_networks`), with no priors."""
        policy, value = tracking_networks(config, generator=generator)
        return Networks(policy, value, motion=None, interaction=())  # type: ignore[arg-type]

    def __init__(
        self,
        config: TrainerConfig,
        data: TrackingData,
        nets: Networks,
        *,
        generator: torch.Generator,
        device: torch.device,
    ):
        self.config = config
        self.key, self.bones = data.key, data.bones
        self.discriminators: tuple[Discriminator, ...] = ()
        # The pushes' own generator (checkpointed with the tracker), so that turning them on
        # leaves every other draw of a run as it was.
        pushes = np.random.default_rng([config.seed, 3])
        self.tracker: Tracker | BoutTracker = (
            BoutTracker(data, config.track, config.env, pushes=pushes)
            if config.track.bouts
            else Tracker(data, config.track, config.env, pushes=pushes, anchored=True)
        )

    def reset(
        self, env: ArenaEnv, ids: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray | Tensor:
        """Reference state initialisation from the task's generator (checkpointed)."""
        return self.tracker.reset(env, ids, rng)

    def step(self, env: ArenaEnv, actions: Tensor) -> tuple[Stepped, dict[str, np.ndarray]]:
        """The policy's actions are corrections (`Tracker.step`); the rollout records the
        rewards and their terms, the errors and which agents' episodes ended terminally."""
        result = self.tracker.step(env, actions.cpu().double().numpy())
        errors = np.stack([result.body_error, result.root_error], -1)
        recorded = {
            "reward": result.reward,
            "reward_terms": result.terms,
            "errors": errors,
            "terminal": result.terminal,
        }
        return result, recorded

    def learn(self, rollout: Rollout, iteration: int, timed: Timed) -> Learned:
        """DeepMimic's rewards, computed as the steps were collected; nothing else learns."""
        assert rollout.reward is not None and rollout.reward_terms is not None
        terms = {k: rollout.reward_terms[..., i] for i, k in enumerate(REWARD_TERMS)}
        terms["total"] = rollout.reward
        return Learned(terms, {}, self._metrics(rollout))

    def _metrics(self, r: Rollout) -> dict[str, float]:
        """A tracking rollout's mean body and root errors (cm, over its stable steps) and its
        drift terminations (an agent's episode ended terminally without a fall) per minute."""
        assert r.errors is not None and r.terminal is not None
        errors = r.errors.reshape(-1, 2)
        errors = errors[torch.isfinite(errors).all(-1)]
        drifts = r.terminal & ~r.fell & ~r.unstable[..., None]
        minutes = r.terminated.numel() / self.config.env.policy_hz / 60
        return {
            "body_error_cm": 100 * float(errors[:, 0].mean()) if len(errors) else math.nan,
            "root_error_cm": 100 * float(errors[:, 1].mean()) if len(errors) else math.nan,
            "drifts_per_min": float(drifts.sum()) / minutes,
        }

    def state(self) -> dict:
        return {"d_optimisers": [], "buffers": [], "tracker": self.tracker.state()}

    def load_state(self, state: Mapping[str, Any]) -> None:
        self.tracker.load_state(state["tracker"])


# The trainer's objectives by `TrainerConfig.objective` (models.maaip.config.OBJECTIVES).
TRAINING_OBJECTIVES: Mapping[str, ObjectiveKind] = {"maaip": MotionPriors, "track": Tracking}


def objective_kind(name: str) -> ObjectiveKind:
    """The objective `TrainerConfig.objective` ``name`` names: the one place it is chosen."""
    return TRAINING_OBJECTIVES[name]
