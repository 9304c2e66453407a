"""The MAAIP training parts (models/maaip/networks.py, losses.py, config.py) against trusted
answers: hand-computed GAE, finite differences, numpy statistics, torch.distributions, and
two short learning runs (a discriminator on synthetic motions, PPO on a one-step bandit)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from models.humanoid.kinematics import HINGE_NAMES, joint_targets_to_action
from models.humanoid.observations import OBSERVATION_DIM, SELF_DIM
from models.maaip.config import (
    DiscriminatorConfig,
    EnvConfig,
    NetworkConfig,
    PPOConfig,
    RewardConfig,
)
from models.maaip.losses import (
    PPOBatch,
    combine_rewards,
    damage_reward,
    discriminator_loss,
    gae,
    gail_discriminator_loss,
    gradient_penalty,
    heading_reward,
    lsgan_discriminator_loss,
    ppo_losses,
    reward_weights,
    style_reward,
)
from models.maaip.networks import (
    ACTION_DIM,
    INTERACTION_INPUT_DIM,
    MOTION_INPUT_DIM,
    CentralValue,
    Discriminator,
    Policy,
    ReplayBuffer,
    RunningNorm,
    action_stds,
    make_networks,
)
from models.maaip.trainer import training_device
from tasks.config import build
from tasks.train.config import TrainConfig

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _generator(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


# --- discriminator -------------------------------------------------------------------------


def _sinusoid_transitions(n: int, generator: torch.Generator, *, consecutive: bool):
    """(n, 2 x 223) transitions of smooth trajectories x_j(t) = a_j sin(w_j t + p_j) at 30 Hz:
    (x(t), x(t + 1/30)) if ``consecutive``, else (x(t), x(s)) of two unrelated trajectory
    points, which have the same marginals but no motion between them."""

    def points(times: torch.Tensor) -> torch.Tensor:
        amp = 0.5 + torch.rand(n, SELF_DIM, generator=generator)
        freq = 1.0 + 5.0 * torch.rand(n, SELF_DIM, generator=generator)
        phase = 2 * math.pi * torch.rand(n, SELF_DIM, generator=generator)
        return amp, freq, phase, amp * torch.sin(freq * times[:, None] + phase)

    t = 10 * torch.rand(n, generator=generator)
    amp, freq, phase, x0 = points(t)
    if consecutive:
        x1 = amp * torch.sin(freq * (t[:, None] + 1 / 30) + phase)
    else:
        x1 = points(10 * torch.rand(n, generator=generator))[3]
    return torch.cat([x0, x1], dim=-1)


@pytest.mark.parametrize("loss", ["gail", "lsgan"])
def test_discriminator_separates_demonstrations_from_random_transitions(loss):
    gen = _generator(0)
    config = DiscriminatorConfig(loss=loss)  # the default gradient penalty and logit weights
    d = Discriminator(MOTION_INPUT_DIM, hidden=(128, 128), generator=gen)
    real_pool = _sinusoid_transitions(16384, gen, consecutive=True)
    fake_pool = ReplayBuffer(16384, MOTION_INPUT_DIM)
    fake_pool.add(_sinusoid_transitions(20000, gen, consecutive=False))  # keeps the last 16384
    assert len(fake_pool) == 16384
    d.norm.update(torch.cat([real_pool, fake_pool.sample(16384, generator=gen)]))
    optimizer = torch.optim.Adam(d.parameters(), lr=1e-3)
    # 500 steps: with 300, one in eight initialisations (seeds 0-3, both losses) fell short.
    for _ in range(500):
        real = real_pool[torch.randint(len(real_pool), (128,), generator=gen)]
        fake = fake_pool.sample(128, generator=gen)
        value, stats = discriminator_loss(d, real, fake, config=config)
        optimizer.zero_grad()
        value.backward()
        optimizer.step()
    assert stats.gradient_penalty > 0
    test = _generator(1)
    with torch.no_grad():
        real_logits = d(_sinusoid_transitions(1000, test, consecutive=True))
        fake_logits = d(_sinusoid_transitions(1000, test, consecutive=False))
    assert (real_logits > 0).float().mean() > 0.9
    assert (fake_logits < 0).float().mean() > 0.9


def test_gradient_penalty_matches_finite_differences():
    torch.manual_seed(0)  # only for the sample data below; the network has its own generator
    d = Discriminator(7, hidden=(16, 16), generator=_generator(3)).double()
    real = torch.randn(5, 7, dtype=torch.float64) * 3 + 1
    fake = torch.randn(6, 7, dtype=torch.float64)
    d.norm.update(torch.cat([real, fake]))
    z = d.normalize(real).detach()

    h = 1e-6
    grads = torch.zeros_like(z)
    with torch.no_grad():
        for j in range(z.shape[1]):
            step = torch.zeros_like(z)
            step[:, j] = h
            grads[:, j] = (d.logits(z + step) - d.logits(z - step)) / (2 * h)
    expected = grads.square().sum(-1).mean().item()

    assert gradient_penalty(d.logits, z).item() == pytest.approx(expected, rel=1e-6)
    with_gp, stats = gail_discriminator_loss(d, real, fake, gp_weight=2.0)
    without_gp, _ = gail_discriminator_loss(d, real, fake, gp_weight=0.0)
    assert stats.gradient_penalty == pytest.approx(expected, rel=1e-6)
    assert (with_gp - without_gp).item() == pytest.approx(2.0 * expected, rel=1e-6)
    # The penalty trains the network (it is differentiable in the weights).
    gradient_penalty(d.logits, z).backward()
    assert d.net[0].weight.grad.abs().sum() > 0


def test_discriminator_losses_match_the_equations():
    d = Discriminator(3, hidden=(8,), generator=_generator(4)).double()
    real = torch.randn(4, 3, generator=_generator(5), dtype=torch.float64)
    fake = torch.randn(6, 3, generator=_generator(6), dtype=torch.float64)
    with torch.no_grad():
        lr, lf = d(real), d(fake)
    sig = torch.sigmoid
    bce = -(sig(lr).log().mean() + (1 - sig(lf)).log().mean())  # eqs 7-8 without the penalty
    gail, stats = gail_discriminator_loss(d, real, fake, gp_weight=0.0, logit_reg=0.5)
    weights = d.output_weight.square().sum()
    assert gail.item() == pytest.approx((bce + 0.5 * weights).item(), rel=1e-10)
    # Counted in float32, as the losses report it.
    assert stats.accuracy_real == pytest.approx((lr > 0).double().mean().item(), abs=1e-7)
    assert stats.accuracy_fake == pytest.approx((lf < 0).double().mean().item(), abs=1e-7)
    ls, _ = lsgan_discriminator_loss(d, real, fake, gp_weight=0.0)
    expected = ((lr - 1) ** 2).mean() + ((lf + 1) ** 2).mean()  # eq 12
    assert ls.item() == pytest.approx(expected.item(), rel=1e-10)
    with pytest.raises(ValueError, match=r"real must have shape \(B, 3\)"):
        gail_discriminator_loss(d, real[:, :2], fake, gp_weight=0.0)


def test_instance_noise_blurs_the_inputs_but_not_the_reported_accuracy():
    d = Discriminator(3, hidden=(8,), generator=_generator(4)).double()
    real = torch.randn(4, 3, generator=_generator(5), dtype=torch.float64) + 2
    fake = torch.randn(6, 3, generator=_generator(6), dtype=torch.float64)
    noisy, stats = gail_discriminator_loss(
        d, real, fake, gp_weight=0.0, input_noise=0.7, generator=_generator(7)
    )
    draws = _generator(7)
    z_real = d.normalize(real) + 0.7 * torch.randn(4, 3, generator=draws, dtype=torch.float64)
    z_fake = d.normalize(fake) + 0.7 * torch.randn(6, 3, generator=draws, dtype=torch.float64)
    sig = torch.sigmoid
    with torch.no_grad():
        bce = -(sig(d.logits(z_real)).log().mean() + (1 - sig(d.logits(z_fake))).log().mean())
        lr, lf = d(real), d(fake)
    assert noisy.item() == pytest.approx(bce.item(), rel=1e-10)
    # Counted in float32, as the losses report it.
    assert stats.accuracy_real == pytest.approx((lr > 0).double().mean().item(), abs=1e-7)
    assert stats.accuracy_fake == pytest.approx((lf < 0).double().mean().item(), abs=1e-7)
    clean, _ = gail_discriminator_loss(d, real, fake, gp_weight=0.0)
    assert clean.item() != pytest.approx(noisy.item())


def test_replay_buffer_is_a_fifo_and_samples_reproducibly():
    buffer = ReplayBuffer(5, 2)
    with pytest.raises(ValueError, match="empty"):
        buffer.sample(3, generator=_generator(0))
    buffer.add(torch.arange(8.0).reshape(4, 2))  # rows 0..3
    buffer.add(torch.arange(8.0, 14.0).reshape(3, 2))  # rows 4..6; rows 0, 1 dropped
    assert len(buffer) == 5
    kept = {tuple(r) for r in buffer.sample(200, generator=_generator(0)).tolist()}
    assert kept == {(2 * i, 2 * i + 1) for i in range(2, 7)}
    a = buffer.sample(10, generator=_generator(7))
    b = buffer.sample(10, generator=_generator(7))
    assert torch.equal(a, b)


# --- rewards -------------------------------------------------------------------------------


def test_style_reward_is_finite_and_monotone_at_extreme_logits():
    logits = torch.tensor([-1e4, -100.0, -10.0, -1.0, 0.0, 1.0, 5.0, 10.0, 100.0, 1e4])
    gail = style_reward(logits, loss="gail", max_reward=9.21)
    assert torch.isfinite(gail).all()
    assert (gail.diff() >= 0).all()
    assert (gail[2:7].diff() > 0).all()  # strictly increasing before the clip
    assert gail[4].item() == pytest.approx(math.log(2))  # D = 1/2: -log(1 - 1/2)
    assert gail[-1].item() == pytest.approx(9.21) and gail[0].item() == 0.0
    # -log(1 - sigmoid(l)) where it can be computed naively
    moderate = torch.linspace(-8, 2, 11, dtype=torch.float64)
    expected = -torch.log(1 - torch.sigmoid(moderate))
    torch.testing.assert_close(style_reward(moderate), expected)

    ls = style_reward(logits, loss="lsgan")
    assert torch.isfinite(ls).all() and (ls >= 0).all() and (ls <= 1).all()
    below = logits[logits <= 1]
    assert (style_reward(below, loss="lsgan").diff() >= 0).all()
    assert style_reward(torch.tensor([1.0, -1.0]), loss="lsgan").tolist() == [1.0, 0.0]
    with pytest.raises(ValueError, match="loss must be"):
        style_reward(logits, loss="wgan")


def test_control_rewards():
    force = torch.tensor([0.0, 50.0, 100.0, 1e6])
    received = damage_reward(force, scale=0.01, maximize=False)  # eq 9
    dealt = damage_reward(force, scale=0.01, maximize=True)  # eq 10
    torch.testing.assert_close(received, torch.exp(-0.01 * force))
    torch.testing.assert_close(received + dealt, torch.ones(4))
    assert (received.diff() < 0).all() and received[0] == 1
    with pytest.raises(ValueError, match="non-negative"):
        damage_reward(-force, scale=0.01, maximize=False)

    d = torch.tensor([[1.0, 0.0]] * 4)
    v = torch.tensor([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.5, 3.0]])
    r = heading_reward(d, v, target_speed=1.0, scale=0.25)
    torch.testing.assert_close(r, torch.exp(-0.25 * torch.tensor([0.0, 1.0, 4.0, 0.25])))


def test_reward_schedule_and_combination():
    config = RewardConfig(
        w_motion=0.1,
        w_interaction=0.4,
        w_control=0.5,
        control_task="damage_min",
        interaction_start=10,
        control_start=20,
        w_alive=0.0,
    )
    assert reward_weights(config, 0) == pytest.approx((1.0, 0.0, 0.0))
    assert reward_weights(config, 10) == pytest.approx((0.2, 0.8, 0.0))  # MAAIP §5.2 weights
    assert reward_weights(config, 20) == pytest.approx((0.1, 0.4, 0.5))  # MAAIP §5.3 weights
    plain = RewardConfig(
        w_motion=0.1,
        w_interaction=0.4,
        w_control=0.5,
        control_task="heading",
        interaction_start=10,
        control_start=20,
        renormalize_schedule=False,
    )
    assert reward_weights(plain, 15) == pytest.approx((0.1, 0.4, 0.0))
    m, i, c = torch.tensor([1.0, 2.0]), torch.tensor([3.0, 4.0]), torch.tensor([5.0, 6.0])
    total = combine_rewards(m, i, c, config=config, iteration=25)
    torch.testing.assert_close(total, 0.1 * m + 0.4 * i + 0.5 * c)
    torch.testing.assert_close(
        combine_rewards(m, i, None, config=config, iteration=12), 0.2 * m + 0.8 * i
    )
    with pytest.raises(ValueError, match="control reward is needed"):
        combine_rewards(m, i, None, config=config, iteration=20)
    # Every step lived earns w_alive on top of eq 4's sum.
    alive = dataclasses.replace(config, w_alive=0.1)
    torch.testing.assert_close(
        combine_rewards(m, i, c, config=alive, iteration=25), 0.1 * m + 0.4 * i + 0.5 * c + 0.1
    )
    with pytest.raises(ValueError, match="w_alive"):
        dataclasses.replace(config, w_alive=-1.0)


# --- GAE and PPO ---------------------------------------------------------------------------


def test_gae_matches_a_hand_computed_case():
    """Column 0: a termination after step 1 (no bootstrap) and a time-out after step 3
    (bootstrap from the last state's value 3.0). Column 1: no episode end."""
    gamma, lam = 0.9, 0.8
    rewards = torch.tensor([[1.0, 1.0], [2.0, 1.0], [3.0, 1.0], [4.0, 1.0]], dtype=torch.float64)
    values = torch.tensor([[0.5, 0], [1.0, 0], [1.5, 0], [2.0, 0]], dtype=torch.float64)
    next_values = torch.tensor([[1.0, 0], [7.0, 0], [2.0, 0], [3.0, 0]], dtype=torch.float64)
    dones = torch.tensor([[0, 0], [1, 0], [0, 0], [1, 0]], dtype=torch.bool)
    timeouts = torch.tensor([[0, 0], [0, 0], [0, 0], [1, 0]], dtype=torch.bool)
    advantages, returns = gae(rewards, values, next_values, dones, timeouts, gamma=gamma, lam=lam)
    # deltas: 1 + .9 * 1 - .5 = 1.4; 2 - 1 = 1 (terminated); 3 + .9 * 2 - 1.5 = 3.3;
    # 4 + .9 * 3 - 2 = 4.7 (time-out bootstraps). gamma * lam = 0.72.
    # A3 = 4.7; A2 = 3.3 + .72 * 4.7 = 6.684; A1 = 1 (episode ended); A0 = 1.4 + .72 = 2.12.
    # Column 1: deltas 1; A = 1, 1.72, 2.2384, 2.611648 backwards.
    expected = torch.tensor(
        [[2.12, 2.611648], [1.0, 2.2384], [6.684, 1.72], [4.7, 1.0]], dtype=torch.float64
    )
    torch.testing.assert_close(advantages, expected)
    torch.testing.assert_close(returns, expected + values)
    with pytest.raises(ValueError, match="timeouts must only be set where dones"):
        gae(rewards, values, next_values, dones, timeouts | True, gamma=gamma, lam=lam)


def _one_sample_batch(policy, value, ratio: float, advantage: float) -> PPOBatch:
    gen = _generator(11)
    obs = torch.randn(1, OBSERVATION_DIM, generator=gen)
    agent = torch.tensor([1])
    actions = torch.randn(1, ACTION_DIM, generator=gen) * 0.1
    with torch.no_grad():
        current = policy.log_prob(obs, agent, actions)
    return PPOBatch(
        policy_inputs=policy.inputs(obs, agent),
        value_inputs=value.inputs(obs, torch.randn(1, OBSERVATION_DIM, generator=gen), agent),
        actions=actions,
        log_probs=current - math.log(ratio),  # so that pi / pi_old = ratio
        advantages=torch.tensor([advantage]),
        returns=torch.tensor([0.0]),
    )


@pytest.mark.parametrize(
    ("ratio", "advantage", "zero"),
    [
        (1.5, 1.0, True),  # clipped above in the advantage's direction
        (0.5, -1.0, True),  # clipped below in the advantage's direction
        (1.5, -1.0, False),  # a worse action made likelier: the gradient pulls back
        (0.5, 1.0, False),
        (1.05, 1.0, False),  # inside the clip range
        (0.95, -1.0, False),
    ],
)
def test_ppo_clipping_zeroes_the_gradient_outside_the_range(ratio, advantage, zero):
    policy = Policy(hidden=(16,), action_std=0.1, generator=_generator(0))
    value = CentralValue(hidden=(16,), generator=_generator(1))
    batch = _one_sample_batch(policy, value, ratio, advantage)
    loss, stats = ppo_losses(
        policy, value, batch, clip=0.2, value_coef=0.0, normalize_advantages=False
    )
    assert stats.ratio == pytest.approx(ratio, rel=1e-4)
    assert stats.clip_fraction == float(abs(ratio - 1) > 0.2)
    loss.backward()
    norm = sum(p.grad.abs().sum() for p in policy.parameters() if p.grad is not None)
    assert (norm == 0) if zero else (norm > 0)


def test_ppo_improves_a_one_step_bandit():
    """Reward -||a - target(o, i)||^2 with a target that depends on the observation and on
    the agent, so the policy must use both inputs; each step ends its episode."""
    gen = _generator(0)
    config = PPOConfig(learning_rate=1e-3, action_std=0.5, epochs=4, minibatch_size=512, horizon=1)
    policy = Policy(hidden=(64, 64), action_std=config.action_std, generator=gen)
    value = CentralValue(hidden=(64, 64), generator=gen)
    optimizer = torch.optim.Adam(
        [*policy.parameters(), *value.parameters()], lr=config.learning_rate
    )

    def target(obs, agent):
        sign = 1.0 - 2.0 * agent[:, None].float()
        return 0.5 * sign + 0.3 * torch.tanh(obs[:, :ACTION_DIM])

    def sample(n):
        obs = torch.randn(n, OBSERVATION_DIM, generator=gen)
        agent = torch.randint(2, (n,), generator=gen)
        return obs, torch.randn(n, OBSERVATION_DIM, generator=gen), agent

    def error():
        obs, _, agent = sample(2000)
        actions, _ = policy.act(obs, agent, deterministic=True)
        return (actions - target(obs, agent)).square().sum(-1).mean().item()

    before = error()
    for _ in range(20):
        obs, other, agent = sample(config.batch_size(num_envs=1024))
        policy.norm.update(obs)
        value.norm.update(torch.cat([obs, other]))
        actions, log_probs = policy.act(obs, agent, generator=gen)
        rewards = -(actions - target(obs, agent)).square().sum(-1)
        with torch.no_grad():
            values = value(obs, other, agent)
        ends = torch.ones(1, len(obs), dtype=torch.bool)
        advantages, returns = gae(
            rewards[None],
            values[None],
            torch.zeros_like(values)[None],
            ends,
            torch.zeros_like(ends),
            gamma=config.gamma,
            lam=config.gae_lambda,
        )
        batch = PPOBatch(
            policy_inputs=policy.inputs(obs, agent),
            value_inputs=value.inputs(obs, other, agent),
            actions=actions,
            log_probs=log_probs,
            advantages=advantages[0],
            returns=returns[0],
        )
        for _ in range(config.epochs):
            order = torch.randperm(len(batch), generator=gen)
            for index in order.split(config.minibatch_size):
                loss, stats = ppo_losses(policy, value, batch.select(index), clip=config.clip_coef)
                optimizer.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(
                    [*policy.parameters(), *value.parameters()], config.max_grad_norm
                )
                optimizer.step()
    after = error()
    assert after < 0.5 * before, (before, after)
    # It learnt to tell the agents apart: their targets differ by 1 in every dimension.
    obs = torch.randn(500, OBSERVATION_DIM, generator=gen)
    gap = policy(obs, 0) - policy(obs, 1)
    assert gap.mean().item() > 0.5


# --- networks ------------------------------------------------------------------------------


def test_running_norm_matches_numpy_over_batches():
    rng = np.random.default_rng(0)
    batches = [rng.normal(1000.0, 3.0, size=(n, 4)) * [1, 2, 0.1, 5] for n in (1, 7, 100, 3)]
    norm = RunningNorm(4, clip=5.0)
    for b in batches:
        norm.update(torch.tensor(b, dtype=torch.float32))
    rows = np.concatenate([b.astype(np.float32) for b in batches]).astype(np.float64)
    np.testing.assert_allclose(norm.mean.numpy(), rows.mean(0), rtol=1e-12)
    np.testing.assert_allclose(norm.var.numpy(), rows.var(0), rtol=1e-9)
    assert norm.count.item() == len(rows)

    x = torch.tensor(rows[:5])
    expected = np.clip((rows[:5] - rows.mean(0)) / np.sqrt(rows.var(0) + 1e-5), -5, 5)
    np.testing.assert_allclose(norm(x).numpy(), expected, rtol=1e-9)
    assert norm(x + 1e6).max().item() == 5.0  # clipped

    restored = RunningNorm(4)
    restored.load_state_dict(norm.state_dict())
    torch.testing.assert_close(restored(x), norm(x))
    with pytest.raises(ValueError, match=r"x must have shape \(\.\.\., 4\)"):
        norm.update(torch.zeros(3, 5))


def test_policy_log_prob_matches_torch_distributions():
    policy = Policy(hidden=(32, 32), action_std=0.055, generator=_generator(0)).double()
    gen = _generator(1)
    obs = torch.randn(6, OBSERVATION_DIM, generator=gen, dtype=torch.float64)
    agent = torch.tensor([0, 1, 0, 1, 1, 0])
    actions = torch.randn(6, ACTION_DIM, generator=gen, dtype=torch.float64) * 0.1
    mean = policy(obs, agent)
    reference = torch.distributions.MultivariateNormal(
        mean, covariance_matrix=0.055**2 * torch.eye(ACTION_DIM, dtype=torch.float64)
    ).log_prob(actions)
    torch.testing.assert_close(policy.log_prob(obs, agent, actions), reference)
    torch.testing.assert_close(policy.distribution(obs, agent).log_prob(actions).sum(-1), reference)
    sampled, log_probs = policy.act(obs, agent, generator=_generator(2))
    again, _ = policy.act(obs, agent, generator=_generator(2))
    torch.testing.assert_close(sampled, again)
    torch.testing.assert_close(log_probs, policy.log_prob(obs, agent, sampled))
    greedy, _ = policy.act(obs, agent, deterministic=True)
    torch.testing.assert_close(greedy, mean.detach())
    # The agent identity is an input: the same observation, different agents, different means.
    same = obs[:1].expand(2, -1)
    assert not torch.allclose(*policy(same, torch.tensor([0, 1])))
    with pytest.raises(ValueError, match=r"agent ids must be in \[0, 2\)"):
        policy(obs, 2)


def test_networks_are_deterministic_given_a_seed_and_have_the_paper_sizes():
    config = TrainConfig(network=NetworkConfig(hidden="32,16"))
    a = make_networks(config, generator=_generator(5))
    b = make_networks(config, generator=_generator(5))
    for x, y in zip(a.policy.parameters(), b.policy.parameters(), strict=True):
        assert torch.equal(x, y)
    assert a.motion.input_dim == MOTION_INPUT_DIM == 446
    assert a.interaction[0].input_dim == INTERACTION_INPUT_DIM == 497
    assert len(a.interaction) == 2
    assert not torch.equal(a.interaction[0].output_weight, a.interaction[1].output_weight)
    assert NetworkConfig(preset="paper").hidden_sizes == (1024, 1024, 512)
    assert [m.out_features for m in a.value.net if isinstance(m, torch.nn.Linear)] == [32, 16, 1]
    heading = make_networks(
        TrainConfig(
            network=NetworkConfig(hidden="8"),
            reward=RewardConfig(w_control=0.5, control_task="heading"),
        ),
        generator=_generator(0),
    )
    obs = torch.zeros(3, OBSERVATION_DIM)
    assert heading.policy(obs, 0, torch.zeros(3, 2)).shape == (3, ACTION_DIM)
    with pytest.raises(ValueError, match="task must be given"):
        heading.policy(obs, 0)


# --- configs -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"w_motion": -0.1}, "train.reward.w_motion must be non-negative"),
        ({"w_interaction": float("nan")}, "train.reward.w_interaction must be non-negative"),
        ({"w_motion": 0.0, "w_interaction": 0.0}, "must be positive; all three weights are 0"),
        ({"w_control": 0.5}, "w_control must be 0 when train.reward.control_task is 'none'"),
        ({"control_task": "damage_max"}, "w_control must be positive when control_task"),
        ({"control_task": "kick"}, "train.reward.control_task must be one of"),
        ({"w_motion": 0.0, "interaction_start": 5}, "every reward active at iteration 0"),
        ({"damage_scale": 0.0}, "train.reward.damage_scale must be positive"),
    ],
)
def test_reward_config_rejects_bad_weights(kwargs, message):
    with pytest.raises(ValueError, match=message):
        RewardConfig(**kwargs)


def test_other_configs_reject_bad_settings():
    with pytest.raises(ValueError, match="train.network.hidden must be comma-separated"):
        NetworkConfig(hidden="256,x")
    with pytest.raises(ValueError, match="train.network.preset must be one of"):
        NetworkConfig(preset="gpu")
    with pytest.raises(ValueError, match="train.discriminator.loss must be one of"):
        DiscriminatorConfig(loss="wgan")
    with pytest.raises(ValueError, match="train.discriminator.gp_weight must be non-negative"):
        DiscriminatorConfig(gp_weight=-1.0)
    with pytest.raises(ValueError, match=r"train.ppo.minibatch_size \(5000\) must not exceed"):
        TrainConfig(ppo=PPOConfig(minibatch_size=5000, horizon=32), env=EnvConfig(num_envs=64))
    with pytest.raises(ValueError, match=r"train.ppo.gamma must be in \(0, 1\]"):
        PPOConfig(gamma=1.5)
    # The config builds from TOML-like tables, nested sections included, with typed values.
    config = build(
        TrainConfig,
        {"seed": "3", "reward": {"w_control": "0.5", "control_task": "heading"}},
        section="train",
    )
    assert config.seed == 3 and config.reward.task_observation_dim == 2


def test_the_paper_preset_is_the_thesis_table_and_a_given_value_wins():
    paper = TrainConfig(preset="paper").with_preset()
    # Table 3.1: 131,072 samples per iteration in 2 minibatches of 6 epochs, episodes of
    # 1,200 steps, gradient penalty 5, K 4,096, action variance 0.0025, clip 0.02.
    assert paper.ppo.batch_size(paper.env.num_envs) == 131072
    assert paper.ppo.batch_size(paper.env.num_envs) // paper.ppo.minibatch_size == 2
    assert paper.ppo.epochs == 6 and paper.env.max_steps == 1200
    assert paper.discriminator.gp_weight == 5 and paper.discriminator.samples_per_update == 4096
    assert paper.ppo.action_std**2 == pytest.approx(0.0025) and paper.ppo.arm_action_std == 0
    assert paper.ppo.clip_coef == 0.02 and paper.network.hidden_sizes == (1024, 1024, 512)
    assert paper.env.stepping == "warp"
    assert TrainConfig() == TrainConfig(preset="cpu").with_preset()
    # Changed in code afterwards, a built config keeps what it is given.
    rollout = dataclasses.replace(paper, env=dataclasses.replace(paper.env, stepping="rollout"))
    assert rollout.env.stepping == "rollout"
    # As `ringside train --train-preset paper --train-env-stepping threads` gives them: a value
    # other than the default wins (one equal to it cannot be told from ringside.toml's own).
    given = build(TrainConfig, {"preset": "paper", "env": {"stepping": "threads"}}, section="train")
    assert given.env.stepping == "threads" and given.env.num_envs == 2048
    # Built again from its own values (a flow's parameters), it is the same config.
    assert build(TrainConfig, dataclasses.asdict(given), section="train") == given
    with pytest.raises(ValueError, match="train.preset must be one of"):
        TrainConfig(preset="gpu")


def test_a_tracker_takes_the_trackers_defaults_and_a_given_value_wins():
    tracker = build(TrainConfig, {"objective": "track"}, section="train")
    assert tracker.ppo.learning_rate == 3e-4 and tracker.ppo.gamma == 0.95
    assert tracker.ppo.action_std == 0.05 and tracker.ppo.arm_action_std == 0
    # MAAIP keeps its own; a tracker given another learning rate keeps it.
    maaip = build(TrainConfig, {}, section="train")
    assert maaip.ppo.learning_rate == 2e-5 and maaip.ppo.gamma == 0.99
    given = build(
        TrainConfig, {"objective": "track", "ppo": {"learning_rate": 1e-4}}, section="train"
    )
    assert given.ppo.learning_rate == 1e-4 and given.ppo.gamma == 0.95
    # The paper preset on a tracker: its arenas, the tracker's learning rate.
    paper = build(TrainConfig, {"objective": "track", "preset": "paper"}, section="train")
    assert paper.env.num_envs == 2048 and paper.ppo.learning_rate == 3e-4


def test_the_training_device_is_chosen_or_refused_clearly():
    with pytest.raises(ValueError, match="train.device must be one of"):
        TrainConfig(device="tpu")
    assert training_device("cpu") == torch.device("cpu")
    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert training_device("auto").type == expected
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="torch sees no GPU"):
            training_device("cuda")


def test_the_policy_starts_from_each_fighters_stance_and_keeps_it_in_its_state():
    stance = np.stack([np.linspace(-0.3, 0.3, ACTION_DIM), np.linspace(0.2, -0.2, ACTION_DIM)])
    guard = torch.from_numpy(joint_targets_to_action(stance)).float()
    obs = torch.randn(64, OBSERVATION_DIM)
    config = TrainConfig(network=NetworkConfig(hidden="32,32"))
    nets = make_networks(config, generator=_generator(0), stance=stance)
    for agent in (0, 1):
        mean = nets.policy(obs, agent)
        # The network's own output starts small (output gain 0.01): the mean is the guard.
        assert (mean - guard[agent]).abs().max() < 0.05
    assert (nets.policy(obs, 0) - nets.policy(obs, 1)).abs().mean() > 0.1
    plain = make_networks(
        dataclasses.replace(config, network=NetworkConfig(hidden="32,32", mean_from_guard=False)),
        generator=_generator(0),
        stance=stance,
    )
    assert plain.policy(obs, 0).abs().max() < 0.05
    restored = make_networks(config, generator=_generator(1))
    restored.policy.load_state_dict(nets.policy.state_dict())
    assert torch.equal(restored.policy(obs, 1), nets.policy(obs, 1))
    with pytest.raises(ValueError, match="actions"):
        nets.policy.start_from(np.zeros((3, ACTION_DIM)))


def test_the_arms_explore_with_their_own_std():
    stds = action_stds(TrainConfig(ppo=PPOConfig(action_std=0.02, arm_action_std=0.1)))
    arms = {h for h in HINGE_NAMES if "shoulder" in h or "elbow" in h}
    for name, std in zip(HINGE_NAMES, stds, strict=True):
        assert std == (0.1 if name in arms else 0.02), name
    off = TrainConfig(ppo=PPOConfig(action_std=0.02, arm_action_std=0.0))
    assert set(action_stds(off)) == {0.02}
    with pytest.raises(ValueError, match="arm_action_std"):
        PPOConfig(arm_action_std=-0.1)
