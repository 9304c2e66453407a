"""MAAIP's rewards and losses as batched pure functions (§4.3, §4.5, §5.3-§5.4, §6.2).

- Discriminators: :func:`gail_discriminator_loss` (eqs 7-8) and
  :func:`lsgan_discriminator_loss` (eq 12), both with the gradient penalty
  :func:`gradient_penalty` on demonstration samples.
- Rewards: :func:`style_reward` (eqs 5-6 for GAIL, eq 13 for LSGAN), :func:`damage_reward`
  (eqs 9-10), :func:`heading_reward` (eq 11, see its note), :func:`combine_rewards` (eq 4 with
  the reward scheduling of §4.5).
- MAPPO: :func:`gae` (GAE(lambda) advantages and TD(lambda) returns) and :func:`ppo_losses`
  (clipped surrogate and value regression).

Shape letters: B batch, F features, A actions, T time steps, N environments x agents.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields

import torch
from torch import Tensor
from torch.nn import functional as F

from models.maaip.config import DiscriminatorConfig, RewardConfig
from models.maaip.networks import CentralValue, Discriminator, Policy


@dataclass(frozen=True)
class DiscriminatorStats:
    """Scalars of one discriminator update, for logging."""

    loss: float  # total minimised
    objective: float  # the cross-entropy (eq 7) or least-squares (eq 12) part
    gradient_penalty: float  # E||grad_z l(z)||^2 on demonstrations, before w_gp
    logit_reg: float  # ||W_out||^2, before its weight
    accuracy_real: float  # fraction of demonstrations with logit > 0
    accuracy_fake: float  # fraction of policy samples with logit < 0
    logit_real: float  # mean logit on demonstrations
    logit_fake: float  # mean logit on policy samples


@dataclass(frozen=True)
class PPOStats:
    """Scalars of one PPO minibatch step, for logging."""

    loss: float
    policy_loss: float
    value_loss: float
    clip_fraction: float  # fraction of samples whose ratio left [1 - eps, 1 + eps]
    approx_kl: float  # E[(r - 1) - log r], Schulman's low-variance KL estimate
    ratio: float  # mean probability ratio


def gradient_penalty(logits: Callable[[Tensor], Tensor], z: Tensor) -> Tensor:
    """E_B ||grad_z logits(z)||^2, differentiable (eqs 7-8's penalty term, before w_gp).

    ``logits`` maps (B, F) to (B,) row by row; ``z`` (B, F) are the points (demonstrations).
    """
    z = z.detach().requires_grad_(True)
    (grad,) = torch.autograd.grad(logits(z).sum(), z, create_graph=True)
    return grad.square().sum(-1).mean()


def _check_pair(d: Discriminator, real: Tensor, fake: Tensor) -> None:
    for name, x in (("real", real), ("fake", fake)):
        if x.ndim != 2 or x.shape[1] != d.input_dim:
            raise ValueError(f"{name} must have shape (B, {d.input_dim}), got {tuple(x.shape)}")


def _discriminator_loss(
    d: Discriminator,
    real: Tensor,
    fake: Tensor,
    objective: Callable[[Tensor, Tensor], Tensor],
    *,
    gp_weight: float,
    logit_reg: float,
    input_noise: float = 0.0,
    generator: torch.Generator | None = None,
) -> tuple[Tensor, DiscriminatorStats]:
    _check_pair(d, real, fake)
    clean_real, clean_fake = d.normalize(real).detach(), d.normalize(fake).detach()
    z_real, z_fake = clean_real, clean_fake
    if input_noise > 0:
        # Instance noise: both sides blurred alike, so no feature separates them exactly.
        z_real = z_real + input_noise * _normal(z_real, generator)
        z_fake = z_fake + input_noise * _normal(z_fake, generator)
    z_real = z_real.requires_grad_(gp_weight > 0)
    logit_real = d.logits(z_real)
    logit_fake = d.logits(z_fake)
    fit = objective(logit_real, logit_fake)
    if gp_weight > 0:
        (grad,) = torch.autograd.grad(logit_real.sum(), z_real, create_graph=True)
        penalty = grad.square().sum(-1).mean()
    else:
        penalty = torch.zeros((), dtype=fit.dtype, device=fit.device)
    weight_norm = d.output_weight.square().sum()
    loss = fit + gp_weight * penalty + logit_reg * weight_norm
    if input_noise > 0:  # accuracies are reported on the samples as they are, never blurred
        with torch.no_grad():
            logit_real, logit_fake = d.logits(clean_real), d.logits(clean_fake)
    stats = DiscriminatorStats(
        loss=loss.item(),
        objective=fit.item(),
        gradient_penalty=penalty.item(),
        logit_reg=weight_norm.item(),
        accuracy_real=(logit_real > 0).float().mean().item(),
        accuracy_fake=(logit_fake < 0).float().mean().item(),
        logit_real=logit_real.mean().item(),
        logit_fake=logit_fake.mean().item(),
    )
    return loss, stats


def _normal(like: Tensor, generator: torch.Generator | None) -> Tensor:
    return torch.randn(like.shape, generator=generator, dtype=like.dtype).to(like.device)


def _cross_entropy(logit_real: Tensor, logit_fake: Tensor) -> Tensor:
    # -E log D(real) - E log(1 - D(fake)), D = sigmoid(l); -log sigmoid(l) = softplus(-l).
    return F.softplus(-logit_real).mean() + F.softplus(logit_fake).mean()


def _least_squares(out_real: Tensor, out_fake: Tensor) -> Tensor:
    return (out_real - 1).square().mean() + (out_fake + 1).square().mean()


def gail_discriminator_loss(
    d: Discriminator,
    real: Tensor,
    fake: Tensor,
    *,
    gp_weight: float,
    logit_reg: float = 0.0,
    input_noise: float = 0.0,
    generator: torch.Generator | None = None,
) -> tuple[Tensor, DiscriminatorStats]:
    """MAAIP eqs 7-8: -E_real log D - E_fake log(1 - D) + w_gp E_real ||grad D||^2.

    ``real`` (B, F) are demonstration transitions, labelled 1, ``fake`` (B', F) the policy's,
    labelled 0. D = sigmoid(logit), evaluated stably through softplus. The penalty's gradient
    is of the logit with respect to the normalised input ``d.normalize(real)`` (eqs 7-8 write
    grad_phi D; following AMP, whose penalty MAAIP adopts, it is taken on the discriminator's
    raw output, and in normalised units so that no feature dominates by its scale). Its
    weight is w_gp as written in eqs 7-8 (no 1/2). ``logit_reg`` adds logit_reg ||W_out||^2.
    ``input_noise`` > 0 adds N(0, input_noise^2) to every normalised input of both sides
    (instance noise, drawn from ``generator``); the reported accuracies and logits are those
    of the inputs as given. Returns the loss to minimise and logging scalars.
    """
    return _discriminator_loss(
        d,
        real,
        fake,
        _cross_entropy,
        gp_weight=gp_weight,
        logit_reg=logit_reg,
        input_noise=input_noise,
        generator=generator,
    )


def lsgan_discriminator_loss(
    d: Discriminator,
    real: Tensor,
    fake: Tensor,
    *,
    gp_weight: float,
    logit_reg: float = 0.0,
    input_noise: float = 0.0,
    generator: torch.Generator | None = None,
) -> tuple[Tensor, DiscriminatorStats]:
    """MAAIP eq 12: E_real (d - 1)^2 + E_fake (d + 1)^2, d the raw output ("logit").

    The same gradient penalty and output regularisation as :func:`gail_discriminator_loss`
    are added (eq 12 omits them; ``gp_weight=0`` gives eq 12 alone). Accuracies count
    d > 0 as "demonstration", the midpoint of the targets +-1.
    """
    return _discriminator_loss(
        d,
        real,
        fake,
        _least_squares,
        gp_weight=gp_weight,
        logit_reg=logit_reg,
        input_noise=input_noise,
        generator=generator,
    )


DISCRIMINATOR_LOSS_FUNCTIONS = {
    "gail": gail_discriminator_loss,
    "lsgan": lsgan_discriminator_loss,
}


def discriminator_loss(
    d: Discriminator,
    real: Tensor,
    fake: Tensor,
    *,
    config: DiscriminatorConfig,
    generator: torch.Generator | None = None,
) -> tuple[Tensor, DiscriminatorStats]:
    """The loss ``config.loss`` names, with its gradient penalty, logit weight and input noise."""
    return DISCRIMINATOR_LOSS_FUNCTIONS[config.loss](
        d,
        real,
        fake,
        gp_weight=config.gp_weight,
        logit_reg=config.logit_reg,
        input_noise=config.input_noise,
        generator=generator,
    )


def style_reward(
    logits: Tensor,
    *,
    loss: str = "gail",
    max_reward: float = 9.21,
    lsgan_offset: float = 1.0,
    lsgan_scale: float = 0.25,
) -> Tensor:
    """A discriminator's reward for each transition, (B,) from logits (B,); no gradient.

    GAIL (eqs 5-6): r = -log(1 - D), D = sigmoid(l), which is exactly softplus(l): finite for
    any finite logit and increasing in it; clipped to [0, max_reward] (9.21 caps D at 0.9999).
    LSGAN (eq 13): r = max(0, u - v (l - 1)^2), u = ``lsgan_offset``, v = ``lsgan_scale``
    (1 and 0.25 bound r in [0, 1]); it peaks at l = 1, the demonstrations' target.
    """
    logits = logits.detach()
    if loss == "gail":
        return F.softplus(logits).clamp(0.0, max_reward)
    if loss == "lsgan":
        return (lsgan_offset - lsgan_scale * (logits - 1).square()).clamp_min(0.0)
    raise ValueError(f"loss must be 'gail' or 'lsgan', got {loss!r}")


def style_reward_from_config(logits: Tensor, config: DiscriminatorConfig) -> Tensor:
    """:func:`style_reward` with the settings of ``config``."""
    return style_reward(
        logits,
        loss=config.loss,
        max_reward=config.max_reward,
        lsgan_offset=config.lsgan_reward_offset,
        lsgan_scale=config.lsgan_reward_scale,
    )


def damage_reward(force: Tensor, *, scale: float, maximize: bool) -> Tensor:
    """MAAIP eqs 9-10 from contact force magnitudes (N), (B,) -> (B,).

    Minimising (eq 9): ``force`` = |f_opp->self|, the opponent's contact normal forces on the
    agent's head, torso and pelvis; r = exp(-w |f|). Maximising (eq 10): ``force`` =
    |f_self->opp| on the opponent's; r = 1 - exp(-w |f|). w = ``scale`` (1/N). Both in [0, 1].
    """
    if not scale > 0:
        raise ValueError(f"scale must be positive, got {scale}")
    if (force < 0).any():
        raise ValueError("force must be non-negative contact force magnitudes (N)")
    decay = torch.exp(-scale * force)
    return 1.0 - decay if maximize else decay


def heading_reward(
    direction: Tensor, root_velocity: Tensor, *, target_speed: float, scale: float
) -> Tensor:
    """Target heading reward (MAAIP eq 11, in the form of AMP's heading task), (B,).

    r = exp(-w (v* - d* . v_root)^2), ``direction`` d* (B, D) a unit vector, ``root_velocity``
    v_root (B, D) in the same frame, v* = ``target_speed``, w = ``scale``; r is in [0, 1] and
    is 1 when moving along d* at v*. Eq 11 as printed, exp(-w (d* . v_root)), would grow
    without bound when moving against d*, contradicting the normalised returns of Table 2 and
    the AMP reward it says it is similar to, so the AMP form is used.
    """
    if direction.shape != root_velocity.shape or direction.ndim != 2:
        raise ValueError(
            "direction and root_velocity must both have shape (B, D), got "
            f"{tuple(direction.shape)} and {tuple(root_velocity.shape)}"
        )
    speed = (direction * root_velocity).sum(-1)
    return torch.exp(-scale * (target_speed - speed).square())


def reward_weights(config: RewardConfig, iteration: int) -> tuple[float, float, float]:
    """(w^M, w^I, w^C) in use at training ``iteration`` (eq 4 with §4.5's scheduling).

    The motion reward is always on; the interaction reward from ``config.interaction_start``
    and the control reward from ``config.control_start``. With ``renormalize_schedule`` the
    active weights are scaled to keep the sum of all three.
    """
    if iteration < 0:
        raise ValueError(f"iteration must be >= 0, got {iteration}")
    on_i = iteration >= config.interaction_start
    on_c = iteration >= config.control_start
    w = (config.w_motion, config.w_interaction * on_i, config.w_control * on_c)
    if config.renormalize_schedule:
        total = config.w_motion + config.w_interaction + config.w_control
        factor = total / sum(w)  # positive: RewardConfig checks iteration 0's weights
        w = tuple(x * factor for x in w)
    return w


def combine_rewards(
    motion: Tensor,
    interaction: Tensor,
    control: Tensor | None,
    *,
    config: RewardConfig,
    iteration: int,
) -> Tensor:
    """r = w^M r^M + w^I r^I (+ w^C r^C) + w_alive, MAAIP eq 4 plus the control reward of §4.5,
    with the weights of :func:`reward_weights`, and a constant reward for every step lived
    (`RewardConfig.w_alive`, not in the paper). All rewards have the same shape."""
    w_m, w_i, w_c = reward_weights(config, iteration)
    if motion.shape != interaction.shape:
        raise ValueError(
            f"motion {tuple(motion.shape)} and interaction {tuple(interaction.shape)} rewards "
            "must have the same shape"
        )
    total = w_m * motion + w_i * interaction
    if w_c > 0:
        if control is None:
            raise ValueError(f"control reward is needed for task {config.control_task!r}")
        if control.shape != motion.shape:
            raise ValueError(
                f"control reward must have shape {tuple(motion.shape)}, got {tuple(control.shape)}"
            )
        total = total + w_c * control
    return total + config.w_alive


def gae(
    rewards: Tensor,
    values: Tensor,
    next_values: Tensor,
    dones: Tensor,
    timeouts: Tensor,
    *,
    gamma: float,
    lam: float,
) -> tuple[Tensor, Tensor]:
    """GAE(lambda) advantages and TD(lambda) returns (Schulman et al. 2015), each (T, N).

    All inputs are (T, N) over steps t. ``values[t]`` = V(s_t); ``next_values[t]`` =
    V(s_t+1) of the state reached by step t, which at an episode's end is the episode's last
    state (not the next episode's first). ``dones[t]``: the episode ended after step t, for
    any reason; ``timeouts[t]``: it ended by the time limit (requires ``dones[t]``). A
    time-out bootstraps from next_values[t]; a termination does not; neither lets the
    advantage flow back across the end:

        delta_t = r_t + gamma (1 - terminated_t) V(s_t+1) - V(s_t)
        A_t     = delta_t + gamma lam (1 - done_t) A_t+1,   returns_t = A_t + V(s_t).
    """
    shape = rewards.shape
    for name, x in (
        ("values", values),
        ("next_values", next_values),
        ("dones", dones),
        ("timeouts", timeouts),
    ):
        if x.shape != shape:
            raise ValueError(f"{name} must have the shape of rewards {tuple(shape)}")
    if rewards.ndim < 1:
        raise ValueError("rewards must have a leading time axis, shape (T, ...)")
    dones, timeouts = dones.bool(), timeouts.bool()
    if (timeouts & ~dones).any():
        raise ValueError("timeouts must only be set where dones is set (a time-out ends it)")
    bootstrap = (~(dones & ~timeouts)).to(rewards.dtype)
    carry = (~dones).to(rewards.dtype)
    deltas = rewards + gamma * bootstrap * next_values - values
    advantages = torch.empty_like(rewards)
    last = torch.zeros_like(rewards[0])
    for t in range(shape[0] - 1, -1, -1):
        last = deltas[t] + gamma * lam * carry[t] * last
        advantages[t] = last
    return advantages, advantages + values


@dataclass(frozen=True)
class PPOBatch:
    """Flattened samples of both agents for PPO, B rows.

    policy_inputs, value_inputs: the networks' inputs (`Policy.inputs`, `CentralValue.inputs`),
    normalised once for the whole update (the normalisers follow the data only after it);
    actions (B, A); log_probs (B,) under the collecting policy; advantages, returns (B,).
    """

    policy_inputs: Tensor
    value_inputs: Tensor
    actions: Tensor
    log_probs: Tensor
    advantages: Tensor
    returns: Tensor

    def __post_init__(self) -> None:
        n = self.policy_inputs.shape[0]
        for f in fields(self):
            x = getattr(self, f.name)
            if x.shape[0] != n:
                raise ValueError(f"PPOBatch.{f.name} has {x.shape[0]} rows, policy_inputs has {n}")

    def __len__(self) -> int:
        return self.policy_inputs.shape[0]

    def select(self, index: Tensor) -> PPOBatch:
        """The rows ``index`` (a minibatch)."""
        # index_select: faster than indexing with a tensor for these row gathers on the CPU.
        return PPOBatch(
            **{f.name: getattr(self, f.name).index_select(0, index) for f in fields(self)}
        )


def ppo_losses(
    policy: Policy,
    value: CentralValue,
    batch: PPOBatch,
    *,
    clip: float,
    value_coef: float = 0.5,
    normalize_advantages: bool = True,
) -> tuple[Tensor, PPOStats]:
    """The PPO loss (Schulman et al. 2017) on ``batch``, MAPPO-style (§4.5).

    loss = -E[min(r A, clip(r, 1 - eps, 1 + eps) A)] + value_coef E[(V(s) - R)^2],
    r = pi(a|o, i) / pi_old(a|o, i), A the advantages (standardised over the batch if
    ``normalize_advantages``), R the TD(lambda) returns, V the centralised value. With A > 0
    and r > 1 + eps (or A < 0 and r < 1 - eps) the surrogate is constant: zero gradient.
    """
    log_probs = policy.log_prob_of(batch.policy_inputs, batch.actions)
    log_ratio = log_probs - batch.log_probs
    ratio = log_ratio.exp()
    adv = batch.advantages
    if normalize_advantages and len(adv) > 1:
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    surrogate = torch.min(ratio * adv, ratio.clamp(1 - clip, 1 + clip) * adv)
    policy_loss = -surrogate.mean()
    predicted = value.value_of(batch.value_inputs)
    value_loss = (predicted - batch.returns).square().mean()
    loss = policy_loss + value_coef * value_loss
    with torch.no_grad():
        stats = PPOStats(
            loss=loss.item(),
            policy_loss=policy_loss.item(),
            value_loss=value_loss.item(),
            clip_fraction=((ratio - 1).abs() > clip).float().mean().item(),
            approx_kl=((ratio - 1) - log_ratio).mean().item(),
            ratio=ratio.mean().item(),
        )
    return loss, stats
