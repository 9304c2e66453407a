"""MAAIP's networks (§4.4) and the discriminators' replay buffer (§4.5), in plain torch.

- :class:`Policy`: one network shared by both agents, fed the agent's normalised observation
  o_t (274) and a one-hot agent identity (2) [and the control task's observation]; it outputs
  the mean mu(o_t, i) of a Gaussian over the 28 PD targets whose covariance is fixed.
- :class:`CentralValue`: the centralised critic of CTDE, fed both agents' observations.
- :class:`Discriminator`: a logit for a transition; the motion prior D^M sees
  (o^self_t, o^self_t+1) (2 x 223), each interaction prior D^I sees (o_t, o^self_t+1)
  (274 + 223).
- :class:`RunningNorm`: running mean and variance of inputs, used by all of them.
- :class:`ReplayBuffer`: a FIFO of policy transitions, the discriminators' negatives.

All take their hidden sizes from :class:`~models.maaip.config.NetworkConfig` (the paper's
1024-1024-512 ReLU or a smaller CPU preset) and a ``torch.Generator`` for their initial
weights, so a seed fixes everything. Shape letters: B batch, F features, A = 28 actions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor, nn

from models.humanoid.kinematics import JOINT_LAYOUT, NUM_ACTUATED, joint_targets_to_action
from models.humanoid.observations import OBSERVATION_DIM, SELF_DIM
from models.maaip.config import NUM_AGENTS, TrainerConfig

ACTION_DIM = NUM_ACTUATED  # 28, as in MAAIP §4.2
# The shoulders' and elbows' actions: exploring them costs no balance (`PPOConfig.arm_action_std`).
ARM_ACTIONS: tuple[int, ...] = tuple(
    i for j in JOINT_LAYOUT if j.group in ("shoulder", "elbow") for i in range(28)[j.action]
)
MOTION_INPUT_DIM = 2 * SELF_DIM  # (o^self_t, o^self_t+1), eqs 5 and 7
INTERACTION_INPUT_DIM = OBSERVATION_DIM + SELF_DIM  # (o_t, o^self_t+1), eqs 6 and 8


def check_features(x: Tensor, name: str, dim: int) -> None:
    """Raise a ValueError naming ``name`` unless ``x`` is a floating (..., dim) tensor."""
    if not isinstance(x, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor of shape (..., {dim}), got {type(x)}")
    if x.ndim < 1 or x.shape[-1] != dim:
        raise ValueError(f"{name} must have shape (..., {dim}), got {tuple(x.shape)}")
    if not x.is_floating_point():
        raise ValueError(f"{name} must be a floating point tensor, got {x.dtype}")


def agent_one_hot(agent: Tensor | int, batch: int, *, like: Tensor) -> Tensor:
    """(B, 2) one-hot identity of each row's agent (0 or 1), MAAIP §4.4."""
    ids = torch.as_tensor(agent, device=like.device)
    if ids.is_floating_point():
        raise ValueError(f"agent must be an integer (tensor), got {ids.dtype}")
    if ids.ndim == 0:
        ids = ids.expand(batch)
    if ids.shape != (batch,):
        raise ValueError(f"agent must be an int or have shape ({batch},), got {tuple(ids.shape)}")
    if ((ids < 0) | (ids >= NUM_AGENTS)).any():
        raise ValueError(f"agent ids must be in [0, {NUM_AGENTS}), got {ids.unique().tolist()}")
    return nn.functional.one_hot(ids.long(), NUM_AGENTS).to(like.dtype)


def mlp(
    in_dim: int,
    hidden: Sequence[int],
    out_dim: int,
    *,
    generator: torch.Generator | None,
    out_gain: float = 1.0,
) -> nn.Sequential:
    """Linear-ReLU layers of sizes ``hidden`` then a linear output (MAAIP §4.4).

    Weights are orthogonal (gain sqrt(2) in hidden layers, ``out_gain`` in the output) drawn
    from ``generator``; biases are zero.
    """
    layers: list[nn.Module] = []
    sizes = [in_dim, *hidden]
    for a, b in zip(sizes[:-1], sizes[1:], strict=True):
        layers += [_linear(a, b, 2.0**0.5, generator), nn.ReLU()]
    layers.append(_linear(sizes[-1], out_dim, out_gain, generator))
    return nn.Sequential(*layers)


def _linear(a: int, b: int, gain: float, generator: torch.Generator | None) -> nn.Linear:
    layer = nn.Linear(a, b)
    with torch.no_grad():
        # Drawn and orthogonalised in float64, then rounded: LAPACK's float32 QR of a tall
        # matrix (the first layer's) gave weights 2e-7 apart in two constructions in one
        # process (MKL's path follows memory alignment), so one seed was not always one run.
        weight = torch.empty(b, a, dtype=torch.float64)
        nn.init.orthogonal_(weight, gain, generator=generator)
        layer.weight.copy_(weight)
        layer.bias.zero_()
    return layer


@dataclass(frozen=True)
class Moments:
    """A batch's row count and per-feature mean and population variance, in float64."""

    count: int
    mean: Tensor
    var: Tensor


@torch.no_grad()
def moments(x: Tensor) -> Moments:
    """The `Moments` of the rows of ``x`` (..., F)."""
    rows = x.detach().reshape(-1, x.shape[-1]).to(torch.float64)
    if rows.shape[0] == 0:
        zeros = rows.new_zeros(rows.shape[1])
        return Moments(0, zeros, zeros)
    return Moments(rows.shape[0], rows.mean(0), rows.var(0, unbiased=False))


class RunningNorm(nn.Module):
    """Normalises features by their running mean and (population) variance, then clips.

    Statistics are float64 buffers, so they are saved in ``state_dict``; :meth:`update`
    merges a batch with Chan et al.'s parallel formula, so after any sequence of updates they
    equal the mean and variance of all rows seen. Before the first update it is the identity
    (mean 0, variance 1), clipped.
    """

    def __init__(self, dim: int, *, clip: float = 5.0, eps: float = 1e-5):
        super().__init__()
        if dim < 1:
            raise ValueError(f"dim must be positive, got {dim}")
        self.dim, self.clip, self.eps = dim, clip, eps
        self.register_buffer("mean", torch.zeros(dim, dtype=torch.float64))
        self.register_buffer("var", torch.ones(dim, dtype=torch.float64))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))

    @torch.no_grad()
    def update(self, x: Tensor) -> None:
        """Add the rows of ``x`` (..., F) to the statistics."""
        check_features(x, "x", self.dim)
        self.merge(moments(x))

    @torch.no_grad()
    def merge(self, batch: Moments) -> None:
        """Add a batch's `moments` to the statistics (one batch's, computed once, can feed
        several normalisers: the policy's and the value's read the same observations)."""
        n, batch_mean, batch_var = batch.count, batch.mean, batch.var
        if batch_mean.shape != (self.dim,):
            raise ValueError(
                f"moments of {tuple(batch_mean.shape)} features for a norm of {self.dim}"
            )
        if n == 0:
            return
        total = self.count + n
        delta = batch_mean - self.mean
        m2 = self.var * self.count + batch_var * n + delta.square() * self.count * n / total
        self.mean.add_(delta * n / total)
        self.var.copy_(m2 / total)
        self.count.copy_(total)

    def forward(self, x: Tensor) -> Tensor:
        """(x - mean) / sqrt(var + eps), clipped to +-clip, in ``x``'s dtype."""
        check_features(x, "x", self.dim)
        mean = self.mean.to(x.dtype)
        std = (self.var + self.eps).sqrt().to(x.dtype)
        return ((x - mean) / std).clamp(-self.clip, self.clip)


class Policy(nn.Module):
    """pi(a | o, i) = N(mu(o, i), sigma^2 I) with a fixed sigma, shared by both agents (§4.4).

    Input: the normalised observation (B, obs_dim), the one-hot agent id (B, 2) and, for a
    control task such as the target heading (§5.4), its observation (B, task_dim).
    """

    def __init__(
        self,
        *,
        hidden: Sequence[int],
        action_std: float | Sequence[float],
        obs_dim: int = OBSERVATION_DIM,
        action_dim: int = ACTION_DIM,
        task_dim: int = 0,
        observation_clip: float = 5.0,
        generator: torch.Generator | None = None,
    ):
        super().__init__()
        std = torch.as_tensor(action_std, dtype=torch.float64).expand(action_dim).clone()
        if not bool((std > 0).all()):
            raise ValueError(f"action_std must be positive, got {action_std}")
        self.obs_dim, self.action_dim, self.task_dim = obs_dim, action_dim, task_dim
        self.norm = RunningNorm(obs_dim, clip=observation_clip)
        self.net = mlp(
            obs_dim + NUM_AGENTS + task_dim, hidden, action_dim, generator=generator, out_gain=0.01
        )
        self.register_buffer("std", std)
        # Each agent's mean is the network's output plus its row: the actions it starts from.
        self.register_buffer("offset", torch.zeros(NUM_AGENTS, action_dim, dtype=torch.float32))

    def inputs(self, obs: Tensor, agent: Tensor | int, task: Tensor | None = None) -> Tensor:
        """(B, obs_dim + 2 [+ task_dim]) the network's input: the normalised observation, the
        one-hot agent id and the task's observation. PPO makes it once per batch, not per
        minibatch (the normaliser does not change during an update)."""
        check_features(obs, "obs", self.obs_dim)
        if obs.ndim != 2:
            raise ValueError(f"obs must have shape (B, {self.obs_dim}), got {tuple(obs.shape)}")
        parts = [self.norm(obs), agent_one_hot(agent, obs.shape[0], like=obs)]
        if self.task_dim:
            if task is None:
                raise ValueError(f"task must be given, shape (B, {self.task_dim})")
            check_features(task, "task", self.task_dim)
            parts.append(task.to(obs.dtype))
        elif task is not None:
            raise ValueError("task must be None for a policy built with task_dim=0")
        return torch.cat(parts, dim=-1)

    def mean_of(self, inputs: Tensor) -> Tensor:
        """mu(o, i) (B, A) from `inputs`: the network's output plus agent i's `offset`."""
        one_hot = inputs[:, self.obs_dim : self.obs_dim + NUM_AGENTS]
        return self.net(inputs) + one_hot @ self.offset.to(inputs.dtype)

    def forward(self, obs: Tensor, agent: Tensor | int, task: Tensor | None = None) -> Tensor:
        """The Gaussian's mean mu(o, i), (B, A): the network's output plus agent i's `offset`."""
        return self.mean_of(self.inputs(obs, agent, task))

    def start_from(self, actions: np.ndarray) -> None:
        """Set each agent's `offset` to ``actions`` (2, A') in its first A' outputs (e.g. its
        guard's PD-target actions), so that an untrained policy holds them."""
        given = torch.as_tensor(np.asarray(actions), dtype=self.offset.dtype)
        if given.ndim != 2 or given.shape[0] != NUM_AGENTS or given.shape[1] > self.action_dim:
            raise ValueError(
                f"actions must have shape ({NUM_AGENTS}, <= {self.action_dim}), "
                f"got {tuple(given.shape)}"
            )
        with torch.no_grad():
            self.offset.zero_()
            self.offset[:, : given.shape[1]] = given

    def distribution(
        self, obs: Tensor, agent: Tensor | int, task: Tensor | None = None
    ) -> torch.distributions.Normal:
        """The per-dimension Normal(mu(o, i), sigma); sum ``log_prob`` over the last axis."""
        mean = self(obs, agent, task)
        return torch.distributions.Normal(mean, self.std.to(mean.dtype).expand_as(mean))

    def log_prob(
        self, obs: Tensor, agent: Tensor | int, actions: Tensor, task: Tensor | None = None
    ) -> Tensor:
        """log pi(a | o, i), (B,)."""
        return self.log_prob_of(self.inputs(obs, agent, task), actions)

    def log_prob_of(self, inputs: Tensor, actions: Tensor) -> Tensor:
        """log pi(a | o, i), (B,), from the network's `inputs`."""
        check_features(actions, "actions", self.action_dim)
        mean = self.mean_of(inputs)
        return _gaussian_log_prob(actions, mean, self.std.to(mean.dtype))

    @torch.no_grad()
    def act(
        self,
        obs: Tensor,
        agent: Tensor | int,
        *,
        task: Tensor | None = None,
        deterministic: bool = False,
        generator: torch.Generator | None = None,
    ) -> tuple[Tensor, Tensor]:
        """Actions (B, A), sampled with ``generator`` or the mean if ``deterministic``, and
        their log-probabilities (B,)."""
        mean = self(obs, agent, task)
        std = self.std.to(mean.dtype)
        if deterministic:
            actions = mean
        else:
            # Drawn on the CPU from the CPU generator whatever the device, so that a seed gives
            # the same noise on a GPU.
            noise = torch.randn(mean.shape, generator=generator, dtype=mean.dtype)
            noise = noise.to(mean.device)
            actions = mean + std * noise
        return actions, _gaussian_log_prob(actions, mean, std)


def _gaussian_log_prob(actions: Tensor, mean: Tensor, std: Tensor) -> Tensor:
    z = (actions - mean) / std
    return (-0.5 * z.square() - std.log() - 0.5 * math.log(2 * math.pi)).sum(-1)


class CentralValue(nn.Module):
    """The centralised value V(o^0, o^1) of CTDE (§4.4), one per agent's reward stream.

    Each agent has its own rewards (its own interaction prior), so the value is asked for one
    agent at a time: input = [norm(o^self), norm(o^other), one-hot id (, task)], i.e. both
    agents' observations, ordered from the asking agent's side (MAPPO's agent-specific global
    state). Output (B,). Without ``sees_other`` (a tracker's, whose agents never meet) it reads
    the asking agent's observation alone and ignores ``other_obs``.
    """

    def __init__(
        self,
        *,
        hidden: Sequence[int],
        obs_dim: int = OBSERVATION_DIM,
        task_dim: int = 0,
        observation_clip: float = 5.0,
        sees_other: bool = True,
        generator: torch.Generator | None = None,
    ):
        super().__init__()
        self.obs_dim, self.task_dim, self.sees_other = obs_dim, task_dim, sees_other
        self.norm = RunningNorm(obs_dim, clip=observation_clip)
        inputs = (2 if sees_other else 1) * obs_dim + NUM_AGENTS + task_dim
        self.net = mlp(inputs, hidden, 1, generator=generator)

    def inputs(
        self,
        obs: Tensor,
        other_obs: Tensor,
        agent: Tensor | int,
        task: Tensor | None = None,
    ) -> Tensor:
        """The network's input: [norm(o^self) (, norm(o^other)), one-hot id (, task)]."""
        check_features(obs, "obs", self.obs_dim)
        check_features(other_obs, "other_obs", self.obs_dim)
        if obs.ndim != 2 or other_obs.shape != obs.shape:
            raise ValueError(
                f"obs and other_obs must both have shape (B, {self.obs_dim}), got "
                f"{tuple(obs.shape)} and {tuple(other_obs.shape)}"
            )
        parts = [self.norm(obs), *([self.norm(other_obs)] if self.sees_other else [])]
        parts.append(agent_one_hot(agent, len(obs), like=obs))
        if self.task_dim:
            if task is None:
                raise ValueError(f"task must be given, shape (B, {self.task_dim})")
            check_features(task, "task", self.task_dim)
            parts.append(task.to(obs.dtype))
        return torch.cat(parts, dim=-1)

    def value_of(self, inputs: Tensor) -> Tensor:
        """V (B,) from the network's `inputs`."""
        return self.net(inputs).squeeze(-1)

    def forward(
        self,
        obs: Tensor,
        other_obs: Tensor,
        agent: Tensor | int,
        task: Tensor | None = None,
    ) -> Tensor:
        return self.value_of(self.inputs(obs, other_obs, agent, task))


class Discriminator(nn.Module):
    """A transition's logit l; D = sigmoid(l) is the probability it is a demonstration.

    ``forward(x)`` takes raw transitions (B, F); :meth:`normalize` and :meth:`logits` are the
    two halves, so the losses can take the gradient penalty in normalised units (see
    :func:`models.maaip.losses.gradient_penalty`).
    """

    def __init__(
        self,
        input_dim: int,
        *,
        hidden: Sequence[int],
        observation_clip: float = 5.0,
        generator: torch.Generator | None = None,
    ):
        super().__init__()
        self.input_dim = input_dim
        self.norm = RunningNorm(input_dim, clip=observation_clip)
        self.net = mlp(input_dim, hidden, 1, generator=generator)

    def normalize(self, x: Tensor) -> Tensor:
        return self.norm(x)

    def logits(self, z: Tensor) -> Tensor:
        """Logits (B,) of normalised transitions ``z`` (B, F)."""
        return self.net(z).squeeze(-1)

    def forward(self, x: Tensor) -> Tensor:
        return self.logits(self.normalize(x))

    @property
    def output_weight(self) -> Tensor:
        """The output layer's weights, for the logit regularisation."""
        return self.net[-1].weight


@dataclass
class Networks:
    """Everything MAAIP trains: the shared policy, the centralised value, the single motion
    prior D^M and one interaction prior D^I per agent (§4.3)."""

    policy: Policy
    value: CentralValue
    motion: Discriminator
    interaction: tuple[Discriminator, ...]


def action_stds(config: TrainerConfig) -> tuple[float, ...]:
    """The fixed exploration std of each of the 28 actions: `ppo.action_std`, and
    `ppo.arm_action_std` on the shoulders and elbows."""
    ppo = config.ppo
    stds = [ppo.action_std] * ACTION_DIM
    if ppo.arm_action_std > 0:
        for i in ARM_ACTIONS:
            stds[i] = ppo.arm_action_std
    return tuple(stds)


def make_networks(
    config: TrainerConfig, *, generator: torch.Generator, stance: np.ndarray | None = None
) -> Networks:
    """All networks with the sizes in ``config``, initialised from ``generator``; with
    `NetworkConfig.mean_from_guard` the policy starts from ``stance`` (2, 28), each fighter's
    guard (`ReferenceMotions.stance`), when given."""
    hidden = config.network.hidden_sizes
    clip = config.network.observation_clip
    task_dim = config.reward.task_observation_dim
    policy = Policy(
        hidden=hidden,
        action_std=action_stds(config),
        task_dim=task_dim,
        observation_clip=clip,
        generator=generator,
    )
    if config.network.mean_from_guard and stance is not None:
        policy.start_from(joint_targets_to_action(np.asarray(stance)))
    return Networks(
        policy=policy,
        value=CentralValue(
            hidden=hidden, task_dim=task_dim, observation_clip=clip, generator=generator
        ),
        motion=Discriminator(
            MOTION_INPUT_DIM, hidden=hidden, observation_clip=clip, generator=generator
        ),
        interaction=tuple(
            Discriminator(
                INTERACTION_INPUT_DIM, hidden=hidden, observation_clip=clip, generator=generator
            )
            for _ in range(NUM_AGENTS)
        ),
    )


class ReplayBuffer:
    """A fixed-size FIFO of transitions (§4.5: replay buffers B^I_i of policy samples).

    ``add`` overwrites the oldest rows once full; ``sample`` draws K rows uniformly (with
    replacement) using the given generator.
    """

    def __init__(
        self,
        capacity: int,
        dim: int,
        *,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ):
        if capacity < 1:
            raise ValueError(f"capacity must be at least 1, got {capacity}")
        self.capacity, self.dim = capacity, dim
        self._data = torch.zeros(capacity, dim, dtype=dtype, device=device)
        self._next = 0
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def add(self, x: Tensor) -> None:
        """Append the rows of ``x`` (B, F), dropping the oldest beyond ``capacity``."""
        check_features(x, "x", self.dim)
        rows = x.detach().reshape(-1, self.dim)[-self.capacity :]
        n = rows.shape[0]
        index = (self._next + torch.arange(n)) % self.capacity
        self._data[index.to(self._data.device)] = rows.to(self._data)
        self._next = (self._next + n) % self.capacity
        self._size = min(self._size + n, self.capacity)

    def state(self) -> dict:
        """What `load_state` takes back: the filled rows only, so a short run's is small."""
        return {"rows": self._data[: self._size].clone(), "next": self._next, "size": self._size}

    def load_state(self, state: dict) -> None:
        rows = state["rows"]
        if rows.shape[1:] != (self.dim,) or len(rows) > self.capacity:
            raise ValueError(
                f"a ReplayBuffer state of {tuple(rows.shape)} rows does not fit one of capacity "
                f"{self.capacity} and width {self.dim}"
            )
        self._data[: len(rows)].copy_(rows)
        self._next, self._size = state["next"], state["size"]

    def sample(self, k: int, *, generator: torch.Generator | None = None) -> Tensor:
        """K rows (K, F) drawn uniformly with replacement."""
        if self._size == 0:
            raise ValueError("cannot sample from an empty ReplayBuffer; add transitions first")
        if k < 1:
            raise ValueError(f"k must be at least 1, got {k}")
        index = torch.randint(self._size, (k,), generator=generator)
        return self._data[index.to(self._data.device)].clone()
