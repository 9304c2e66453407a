"""MAAIP's training loop: MAPPO with a motion prior and one interaction prior per agent.

MAAIP Algorithm 1 (§4.5), one iteration:
1. collect T steps of N two-fighter environments with the shared policy (both agents);
2. rewards: r^M from the motion discriminator on (o^self_t, o^self_t+1), r^I_i from agent i's
   interaction discriminator on (o_t, o^self_t+1) (eqs 5-6), a control reward if asked
   (eqs 9-11), combined with the scheduled weights (eq 4);
3. the policy's transitions go into each discriminator's replay buffer; each discriminator
   takes `updates_per_iteration` steps on K demonstration and K replayed transitions
   (eqs 7-8 or 12-13);
4. GAE(lambda) advantages and TD(lambda) returns per agent; PPO epochs over minibatches of
   both agents' samples for the policy and the centralised value.

Steps 2-3 are the objective's (`models.maaip.objectives`, chosen once by
`TrainerConfig.objective`): MAAIP's priors (`MotionPriors`), or a tracker (`Tracking`,
`models.tracking`), whose actions are reference frames plus the policy's corrections and whose
reward is DeepMimic's, computed as the steps are collected, with no discriminators. The
collection, GAE, PPO, the normalisers and the checkpoints are the same loop for both.

Everything that decides what comes next is one :class:`TrainState` (`Trainer.state`,
`Trainer.load`; `Trainer.checkpoint` is its bytes): networks, optimisers, normalisers, replay
buffers, random generators, the environments' physics states and the iteration, so a run
restored from a checkpoint continues exactly as the uninterrupted run would (tested, with each
stepping). The trainer builds its arena and networks with the factories it is given (`ArenaEnv`
and `default_networks` unless told), and imports no storage, Prefect or stage code: the train
stage (`tasks.train`) runs it.
"""

from __future__ import annotations

import io
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import Tensor

from models.arena.config import EnvConfig
from models.arena.env import ArenaEnv
from models.humanoid.boxer import BoneLengths
from models.maaip.config import TrainerConfig
from models.maaip.demonstrations import Demonstrations
from models.maaip.distill import distill
from models.maaip.losses import PPOBatch, gae, ppo_losses
from models.maaip.networks import Networks, Policy, action_stds, moments
from models.maaip.objectives import Objective, Rollout, objective_kind
from models.tracking.clips import TrackingData

# 2: the policy's offset (its guard) is part of its state; 3: a `TrainState` (the arena's and
# the replay buffers' own states). Export and warm starts read the networks of any format.
CHECKPOINT_FORMAT = 3


def checkpoint_policy(blob: bytes, config: TrainerConfig) -> tuple[Policy, tuple[BoneLengths, ...]]:
    """The policy of a `Trainer.checkpoint` made with ``config`` (a tracker's sees the
    tracker's observation), in eval mode, and the run's two humanoids."""
    state = _load(blob)
    policy = Policy(
        hidden=config.network.hidden_sizes,
        action_std=action_stds(config),
        obs_dim=objective_kind(config.objective).observation_dim,
        task_dim=config.reward.task_observation_dim,
        observation_clip=config.network.observation_clip,
    )
    weights = dict(state["networks"]["policy"])
    # A policy trained before it had an offset acted from the rest pose: a zero offset.
    weights.setdefault("offset", policy.offset.clone())
    policy.load_state_dict(weights)
    policy.eval()
    return policy, tuple(BoneLengths(**b) for b in state["signature"]["bones"])


class CheckpointMismatch(ValueError):
    """A checkpoint that does not belong to this run (other humanoid, sizes or dataset)."""


def training_device(name: str) -> torch.device:
    """The torch device for `TrainerConfig.device`; a clear error if 'cuda' is asked without one."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError(
            "train.device is 'cuda' but torch sees no GPU (torch.cuda.is_available() is False); "
            "use 'auto' or 'cpu'"
        )
    return torch.device(name)


def _signature(config: TrainerConfig, key: str, bones: tuple, observation_dim: int) -> dict:
    """What a checkpoint must agree on to be resumed: the data, the humanoids and the network
    sizes (a tracker's observation, 451, tells its checkpoints from MAAIP's, 274)."""
    return {
        "format": CHECKPOINT_FORMAT,
        "dataset_key": key,
        "bones": [asdict(b) for b in bones],
        "observation_dim": observation_dim,
        "hidden": list(config.network.hidden_sizes),
        "task_dim": config.reward.task_observation_dim,
    }


# Builds the arena: (EnvConfig, its generator, the two humanoids, the torch device's name).
ArenaFactory = Callable[[EnvConfig, np.random.Generator, tuple, str], ArenaEnv]
# Builds the networks for the run's config and data from its generator.
NetworksFactory = Callable[
    [TrainerConfig, "Demonstrations | TrackingData", torch.Generator], Networks
]


def default_networks(
    config: TrainerConfig, data: Demonstrations | TrackingData, generator: torch.Generator
) -> Networks:
    """The networks of ``config``'s objective: MAAIP's (the policy starting from the dataset's
    guard), or a tracker's: its policy and value, with no priors."""
    return objective_kind(config.objective).networks(config, data, generator)


@dataclass
class TrainState:
    """Everything that decides what a run does next, saved and restored as one object
    (`Trainer.state`, `Trainer.load`): networks (normalisers included), optimisers, replay
    buffers, random generators, the environments and the iteration."""

    signature: dict
    iteration: int
    networks: dict  # state dicts: policy, value, discriminators (a list)
    optimiser: dict
    d_optimisers: list
    buffers: list  # `ReplayBuffer.state` of each discriminator's
    torch_generator: Tensor
    torch_rng: Tensor
    task_rng: dict
    targets: np.ndarray
    obs: np.ndarray
    arena: dict  # `ArenaEnv.state`
    tracker: dict | None  # `Tracker.state`

    def to_bytes(self) -> bytes:
        out = io.BytesIO()
        torch.save(asdict(self), out)
        return out.getvalue()

    @classmethod
    def from_bytes(cls, blob: bytes) -> TrainState:
        """The state of a `to_bytes`; CheckpointMismatch, in one line, for another format."""
        found = _load(blob)
        version = found.get("signature", {}).get("format")
        if version != CHECKPOINT_FORMAT:
            raise CheckpointMismatch(
                f"checkpoint format {version} cannot be resumed by this version (format "
                f"{CHECKPOINT_FORMAT}): start the run again (`--rerun`)"
            )
        return cls(**found)


def _load(blob: bytes) -> dict:
    return torch.load(io.BytesIO(blob), weights_only=False, map_location="cpu")


class Trainer:
    """One training run on one dataset; `iterate` runs Algorithm 1 once (or, with objective
    'track', its collection and PPO steps on the tracking reward).

    ``data`` is the dataset's Demonstrations for 'maaip', the clips to track (TrackingData)
    for 'track'.
    """

    def __init__(
        self,
        config: TrainerConfig,
        data: Demonstrations | TrackingData,
        *,
        arena: ArenaFactory = ArenaEnv,
        networks: NetworksFactory | None = None,
    ):
        torch.manual_seed(config.seed)
        kind = objective_kind(config.objective)
        if not isinstance(data, kind.data_type):
            raise ValueError(
                f"train.objective {config.objective!r} trains on {kind.data_type.__name__}, "
                f"got {type(data).__name__}"
            )
        self.config = config
        self.device = training_device(config.device)
        # One CPU generator draws every random number (then moved), so a seed means the same
        # run on either device up to floating point.
        self.generator = torch.Generator().manual_seed(config.seed)
        self.nets = (networks or default_networks)(config, data, self.generator)
        for net in (self.nets.policy, self.nets.value):
            net.to(self.device)
        # Fused: one kernel per step for all parameters; the default's per-tensor steps were 18 %
        # of a tracker's CPU update (torch.profiler, 2026-12-02; the discriminators' likewise).
        self.optimiser = torch.optim.Adam(
            [*self.nets.policy.parameters(), *self.nets.value.parameters()],
            lr=config.ppo.learning_rate,
            fused=True,
        )
        # What the objective adds: its discriminators, their optimisers and buffers, or a tracker.
        self.objective: Objective = kind(
            config, data, self.nets, generator=self.generator, device=self.device
        )
        key, bones = self.objective.key, self.objective.bones
        self.env = arena(config.env, np.random.default_rng(config.seed), bones, str(self.device))
        # The heading task (§5.4): each agent's target direction on the floor, a world yaw drawn
        # anew at every episode start.
        self.heading = config.reward.control_task == "heading"
        self.task_rng = np.random.default_rng([config.seed, 1])
        self.targets = np.zeros((self.env.num_envs, 2))
        # The current observations, on the training device.
        self.obs = self._tensor(self._reset(np.arange(self.env.num_envs)))
        self.finished_steps = np.zeros(0, dtype=int)
        self.iteration = 0
        self.signature = _signature(config, key, bones, self.nets.policy.obs_dim)

    @property
    def discriminators(self) -> tuple:
        """The networks the objective trains beside the policy and value (none for a tracker)."""
        return self.objective.discriminators

    def close(self) -> None:
        self.env.close()

    def _reset(self, ids: np.ndarray) -> np.ndarray | Tensor:
        if self.heading:
            self.targets[ids] = self.task_rng.uniform(-np.pi, np.pi, (len(ids), 2))
        return self.objective.reset(self.env, ids, self.task_rng)

    def task_observation(self) -> Tensor | None:
        """(N, 2, 2) each agent's target direction in its own heading frame, or None."""
        if not self.heading:
            return None
        return self._tensor(self.env.heading_inputs(self.targets))

    def _tensor(self, array: np.ndarray | Tensor) -> Tensor:
        """A float32 (or bool) tensor of an environment array (NumPy, or a tensor where the
        arena computed it on a device: Warp), on the training device."""
        tensor = torch.as_tensor(array)
        if tensor.dtype != torch.bool:
            tensor = tensor.to(dtype=torch.float32)
        return tensor.to(self.device)

    # ------------------------------------------------------------------ collect

    def collect(self) -> Rollout:
        """T policy steps of every environment; finished episodes restart from the demos."""
        n, horizon = self.env.num_envs, self.config.ppo.horizon
        agents = torch.arange(2, device=self.device).repeat(n)
        parts: dict[str, list] = {k: [] for k in Rollout.__dataclass_fields__}
        finished: list[np.ndarray] = []
        for _ in range(horizon):
            obs = self.obs
            task = self.task_observation()
            actions, log_probs = self.nets.policy.act(
                obs.reshape(2 * n, -1),
                agents,
                task=None if task is None else task.reshape(2 * n, -1),
                generator=self.generator,
            )
            result, recorded = self.objective.step(self.env, actions.reshape(n, 2, -1))
            for name, value in recorded.items():
                parts[name].append(self._tensor(value))
            parts["obs"].append(obs)
            # Where the arena observed on a device (Warp), from there: no trip through the host.
            # (A tracker's observations are its own, made on the host.)
            next_obs = self._tensor(result.observation)
            parts["next_obs"].append(next_obs)
            parts["actions"].append(actions.reshape(n, 2, -1))
            parts["log_probs"].append(log_probs.reshape(n, 2))
            parts["damage"].append(self._tensor(result.damage))
            parts["terminated"].append(self._tensor(result.terminated))
            parts["truncated"].append(self._tensor(result.truncated))
            parts["fell"].append(self._tensor(result.fell))
            parts["unstable"].append(self._tensor(result.unstable))
            if task is not None:
                parts["task"].append(task)
                # Eq 11 rewards the move just made towards the targets it was made for.
                parts["next_task"].append(self.task_observation())
            self.obs = next_obs
            done = np.flatnonzero(result.done)
            if done.size:
                finished.append(self.env.elapsed[done].copy())
                self.obs = self.obs.clone()
                self.obs[done.tolist()] = self._tensor(self._reset(done))
        self.finished_steps = np.concatenate(finished) if finished else np.zeros(0, dtype=int)
        return Rollout(**{k: torch.stack(v) if v else None for k, v in parts.items()})

    # ------------------------------------------------------------------ PPO

    def update_policy(self, r: Rollout, reward: Tensor) -> dict[str, float]:
        """GAE per agent, then PPO epochs over minibatches of both agents' samples."""
        ppo = self.config.ppo
        horizon, n, _ = r.log_probs.shape
        policy, value = self.nets.policy, self.nets.value
        # Each agent's opponent's observation, the value's input where it sees the partner (a
        # tracker's does not, and is handed its own, unread, to save the copy).
        partner = (lambda x: x.flip(2)) if value.sees_other else (lambda x: x)  # noqa: E731
        agent = torch.arange(2, device=self.device).expand(horizon, n, 2).reshape(-1)
        flat = lambda x: None if x is None else x.reshape(-1, x.shape[-1])  # noqa: E731
        with torch.no_grad():
            # The networks' inputs, normalised once for the whole update: the normalisers follow
            # the data only after it.
            value_inputs = value.inputs(flat(r.obs), flat(partner(r.obs)), agent, flat(r.task))
            policy_inputs = policy.inputs(flat(r.obs), agent, flat(r.task))
            values = value.value_of(value_inputs)
            next_values = value(
                flat(r.next_obs), flat(partner(r.next_obs)), agent, flat(r.next_task)
            )
        dones = (r.terminated | r.truncated)[..., None].expand(horizon, n, 2)
        timeouts = r.truncated[..., None].expand(horizon, n, 2)
        if r.terminal is not None:
            timeouts = dones & ~r.terminal  # the other agent's ending is a time-out for it
        advantages, returns = gae(
            reward.reshape(horizon, -1),
            values.reshape(horizon, -1),
            next_values.reshape(horizon, -1),
            dones.reshape(horizon, -1),
            timeouts.reshape(horizon, -1),
            gamma=ppo.gamma,
            lam=ppo.gae_lambda,
        )
        batch = PPOBatch(
            policy_inputs=policy_inputs,
            value_inputs=value_inputs,
            actions=flat(r.actions),
            log_probs=r.log_probs.reshape(-1),
            advantages=advantages.reshape(-1),
            returns=returns.reshape(-1),
        )
        params = [*self.nets.policy.parameters(), *self.nets.value.parameters()]
        kls = []
        last = None
        for _ in range(ppo.epochs):
            order = torch.randperm(len(batch), generator=self.generator).to(self.device)
            for start in range(0, len(batch) - ppo.minibatch_size + 1, ppo.minibatch_size):
                loss, last = ppo_losses(
                    self.nets.policy,
                    self.nets.value,
                    batch.select(order[start : start + ppo.minibatch_size]),
                    clip=ppo.clip_coef,
                    value_coef=ppo.value_coef,
                    normalize_advantages=ppo.normalize_advantages,
                )
                self.optimiser.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(params, ppo.max_grad_norm)
                self.optimiser.step()
                kls.append(last.approx_kl)
        # The normalisers follow the data after the update, so the samples above were
        # scored with the statistics they were collected under.
        seen = moments(flat(r.obs))
        self.nets.policy.norm.merge(seen)
        self.nets.value.norm.merge(seen)
        assert last is not None
        return {
            "policy_loss": last.policy_loss,
            "value_loss": last.value_loss,
            "clip_fraction": last.clip_fraction,
            "approx_kl": float(np.mean(kls)),
        }

    # ------------------------------------------------------------------ one iteration

    def iterate(self) -> dict[str, float]:
        """Algorithm 1 once; returns the iteration's metrics."""
        timings: dict[str, float] = {}

        def timed(name: str, fn: Callable, *args):
            start = time.perf_counter()
            out = fn(*args)
            timings[name] = time.perf_counter() - start
            return out

        # Torch gets one thread while MuJoCo's workers step the batch, and the env's cores for
        # the updates (measured with the cpu preset: updates 1.6x faster than on one thread).
        torch.set_num_threads(1)
        rollout = timed("collect_s", self.collect)
        torch.set_num_threads(self.env.config.threads)
        learned = self.objective.learn(rollout, self.iteration, timed)
        terms = learned.rewards
        p_stats = timed("ppo_s", self.update_policy, rollout, terms["total"])
        steps = rollout.terminated.numel()  # environment steps (both agents move in each)
        seconds = sum(timings.values())
        sim_minutes = steps / self.env.config.policy_hz / 60
        hz = self.env.config.policy_hz
        # Episodes that ended in this iteration, by their whole length; an iteration in which
        # none ended has no such mean and leaves the metric out (the running episodes' mean
        # age is `episode_age_s`, about half of it).
        lengths = self.finished_steps
        finished = {"episode_length_s": float(lengths.mean()) / hz} if lengths.size else {}
        metrics = {
            **finished,
            **{f"reward_{k}": float(v.mean()) for k, v in terms.items()},
            **learned.stats,
            **p_stats,
            **timings,
            "env_steps_per_s": steps / seconds,
            "falls_per_min": float(rollout.fell.any(-1).sum()) / sim_minutes,
            "unstable_episodes": float(rollout.unstable.sum()),
            "episodes_ended": float((rollout.terminated | rollout.truncated).sum()),
            "episode_age_s": float(self.env.elapsed.mean()) / hz,
            "damage_received_n": float(rollout.damage.mean()),
            **learned.metrics,
        }
        self.iteration += 1
        return metrics

    # ------------------------------------------------------------------ checkpoints

    def state(self) -> TrainState:
        """Everything needed to continue exactly from here."""
        return TrainState(
            signature=self.signature,
            iteration=self.iteration,
            networks={
                "policy": self.nets.policy.state_dict(),
                "value": self.nets.value.state_dict(),
                "discriminators": [d.state_dict() for d in self.discriminators],
            },
            optimiser=self.optimiser.state_dict(),
            torch_generator=self.generator.get_state(),
            torch_rng=torch.get_rng_state(),
            task_rng=self.task_rng.bit_generator.state,
            targets=self.targets.copy(),
            obs=self.obs.cpu().numpy().copy(),
            arena=self.env.state(),
            **self.objective.state(),  # d_optimisers, buffers, tracker
        )

    def checkpoint(self) -> bytes:
        """`state` as bytes."""
        return self.state().to_bytes()

    def warm_start(self, blob: bytes) -> None:
        """Start from the networks of another run's `checkpoint` (its policy, value and
        discriminators, normalisers included), at iteration 0 with fresh optimisers and replay
        buffers; CheckpointMismatch unless its humanoids and network sizes are this run's."""
        state = _load(blob)
        theirs = state.get("signature", {})
        shared = ("bones", "observation_dim", "hidden", "task_dim")
        differs = sorted(k for k in shared if theirs.get(k) != self.signature[k])
        if differs:
            raise CheckpointMismatch(
                f"cannot start from that run's networks: its {', '.join(differs)} differ"
            )
        networks = state["networks"]
        self.nets.policy.load_state_dict(networks["policy"])
        self.nets.value.load_state_dict(networks["value"])
        for d, s in zip(self.discriminators, networks["discriminators"], strict=True):
            d.load_state_dict(s)

    def distill_from(self, teacher: Policy, data: TrackingData) -> list[dict[str, float]]:
        """Fit this run's policy to tracker ``teacher``'s actions on ``data``, the two
        fighters' footage clips paired (`models.maaip.distill`), before the first iteration;
        each round's figures."""
        if self.iteration:
            raise ValueError(
                f"a run distils before its first iteration, not at iteration {self.iteration}"
            )
        self.nets.policy.cpu()
        rounds = distill(
            self.nets.policy,
            teacher.cpu(),
            data,
            self.config,
            generator=self.generator,
            rng=np.random.default_rng([self.config.seed, 2]),
        )
        self.nets.policy.to(self.device)
        return rounds

    def restore(self, blob: bytes) -> None:
        """Continue from a `checkpoint`; CheckpointMismatch if it belongs to another run."""
        self.load(TrainState.from_bytes(blob))

    def load(self, state: TrainState) -> None:
        """Continue from ``state``; CheckpointMismatch if it belongs to another run."""
        theirs = state.signature
        differs = sorted(k for k in self.signature if theirs.get(k) != self.signature[k])
        if differs:
            first = differs[0]
            raise CheckpointMismatch(
                f"checkpoint was made for another run: its {', '.join(differs)} differ "
                f"({first}: {theirs.get(first)!r} there, {self.signature[first]!r} here)"
            )
        self.iteration = state.iteration
        self.nets.policy.load_state_dict(state.networks["policy"])
        self.nets.value.load_state_dict(state.networks["value"])
        for d, s in zip(self.discriminators, state.networks["discriminators"], strict=True):
            d.load_state_dict(s)
        self.optimiser.load_state_dict(state.optimiser)
        self.objective.load_state(vars(state))
        self.generator.set_state(state.torch_generator)
        torch.set_rng_state(state.torch_rng)
        self.task_rng.bit_generator.state = state.task_rng
        self.targets = state.targets.copy()
        self.env.load_state(state.arena)
        self.obs = self._tensor(state.obs)
