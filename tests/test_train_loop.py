"""MAAIP's training loop on a tiny setup: one iteration's pieces, checkpoints and resumption."""

from __future__ import annotations

import dataclasses
import io

import numpy as np
import pytest
import torch
from training_runs import parameters, resumes_exactly

from models.arena.env import ArenaEnv
from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import heading_yaw
from models.maaip.config import (
    DiscriminatorConfig,
    EnvConfig,
    NetworkConfig,
    PPOConfig,
    RewardConfig,
)
from models.maaip.demonstrations import Demonstrations
from models.maaip.trainer import CheckpointMismatch, Trainer, TrainState, default_networks
from tasks.train.config import TrainConfig
from tasks.train.data import clip_demonstrations

TINY = TrainConfig(
    seed=3,
    network=NetworkConfig(hidden="32,32"),
    discriminator=DiscriminatorConfig(samples_per_update=32, updates_per_iteration=2),
    ppo=PPOConfig(horizon=8, minibatch_size=32, epochs=2),
    env=EnvConfig(num_envs=4, threads=2),
)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


DEFAULT_BONES = (BoneLengths(), BoneLengths())


def _demos(assets, bones=DEFAULT_BONES) -> Demonstrations:
    """The punch clip performed by two fighters facing each other, as a dataset would hold it."""
    return clip_demonstrations(assets, "punch", bones)


@pytest.fixture(scope="module")
def demos(assets) -> Demonstrations:
    return _demos(assets)


def test_one_iteration_reports_every_term(demos):
    trainer = Trainer(TINY, demos)
    try:
        before = parameters(trainer)
        metrics = trainer.iterate()
    finally:
        trainer.close()
    for name in (
        "reward_motion",
        "reward_interaction",
        "reward_total",
        "motion_accuracy_real",
        "interaction0_accuracy_fake",
        "motion_gradient_penalty",
        "episode_age_s",
        "falls_per_min",
        "damage_received_n",
        "env_steps_per_s",
        "collect_s",
        "ppo_s",
    ):
        assert np.isfinite(metrics[name]), name
    assert 0 <= metrics["reward_motion"] <= TINY.discriminator.max_reward
    assert trainer.iteration == 1
    assert not torch.equal(before, parameters(trainer)), "nothing was learned"


def test_episode_length_is_the_mean_length_of_the_episodes_that_ended(demos):
    # Episodes of 3 steps in an iteration of 8: every environment ends at least two episodes,
    # and the running ones are younger than the ended ones.
    short = dataclasses.replace(TINY, env=dataclasses.replace(TINY.env, episode_s=0.1))
    trainer = Trainer(short, demos)
    try:
        metrics = trainer.iterate()
        ended = trainer.finished_steps
    finally:
        trainer.close()
    assert len(ended) >= 2 * short.env.num_envs
    assert ended.max() == 3 and ended.min() >= 1
    assert metrics["episode_length_s"] == pytest.approx(ended.mean() / 30)
    assert metrics["episodes_ended"] == len(ended)
    assert metrics["episode_age_s"] < metrics["episode_length_s"] + 1e-9


@pytest.mark.parametrize(
    ("task", "stepping"),
    [("none", "rollout"), ("heading", "rollout"), ("none", "warp"), ("heading", "warp")],
)
def test_resumed_run_matches_the_uninterrupted_one(demos, task, stepping):
    reward = RewardConfig(w_control=0.5 if task == "heading" else 0.0, control_task=task)
    env = dataclasses.replace(TINY.env, stepping=stepping)
    config = dataclasses.replace(TINY, reward=reward, env=env)
    resumes_exactly(config, demos)


def test_a_checkpoint_of_another_humanoid_is_refused(demos, assets):
    trainer = Trainer(TINY, demos)
    try:
        blob = trainer.checkpoint()
    finally:
        trainer.close()
    taller = dataclasses.replace(BoneLengths(), thigh=0.5)
    other = Trainer(TINY, dataclasses.replace(demos, bones=(taller, BoneLengths())))
    try:
        with pytest.raises(CheckpointMismatch, match="bones differ"):
            other.restore(blob)
    finally:
        other.close()


def test_a_checkpoint_is_one_train_state_and_an_older_format_is_refused_in_one_line(demos):
    trainer = Trainer(TINY, demos)
    try:
        trainer.iterate()
        state = TrainState.from_bytes(trainer.checkpoint())
    finally:
        trainer.close()
    assert state.iteration == 1 and len(state.buffers) == 3
    assert state.arena["physics"].shape[0] == TINY.env.num_envs
    older = {**dataclasses.asdict(state), "signature": {**state.signature, "format": 2}}
    out = io.BytesIO()
    torch.save(older, out)
    with pytest.raises(CheckpointMismatch, match="format 2 cannot be resumed") as error:
        TrainState.from_bytes(out.getvalue())
    assert "\n" not in str(error.value)


def test_the_trainer_builds_its_arena_and_networks_with_the_factories_it_is_given(demos):
    made = []

    def arena(config, rng, bones, device):
        made.append(ArenaEnv(dataclasses.replace(config, stepping="threads"), rng, bones, device))
        return made[-1]

    def networks(config, data, generator):
        made.append(default_networks(config, data, generator))
        return made[-1]

    trainer = Trainer(TINY, demos, arena=arena, networks=networks)
    try:
        assert trainer.nets is made[0] and trainer.env is made[1]
        assert trainer.env.config.stepping == "threads"
        before = made[1].state()["physics"]
        trainer.iterate()
        assert not np.array_equal(made[1].state()["physics"], before)  # the arena given is stepped
    finally:
        trainer.close()


def test_the_heading_task_rewards_moving_along_the_target(demos):
    reward = RewardConfig(w_control=0.5, control_task="heading", control_start=0)
    trainer = Trainer(dataclasses.replace(TINY, reward=reward), demos)
    try:
        task = trainer.task_observation().numpy()
        assert task.shape == (4, 2, 2)
        np.testing.assert_allclose(np.linalg.norm(task, axis=-1), 1, atol=1e-6)
        # The target seen from agent 0 of env 0, turned back into the world, is its target.
        quat = trainer.env.datas[0].qpos[trainer.env.index.agents[0].qpos][3:7]
        angle = np.arctan2(task[0, 0, 1], task[0, 0, 0]) + heading_yaw(quat)
        assert np.isclose(np.cos(angle - trainer.targets[0, 0]), 1, atol=1e-5)
        metrics = trainer.iterate()
        assert 0 <= metrics["reward_control"] <= 1 and metrics["w_control"] > 0
        # A rollout's moves replaced by moves along each agent's target at the target speed,
        # and against it: the pelvis's velocity in the heading frame, where its target is seen
        # after the step. Along earns eq 11's 1, against exp(-w (2 v*)^2).
        from models.humanoid.observations import SELF_BLOCKS, block_slices

        rollout = trainer.collect()
        pelvis = block_slices(SELF_BLOCKS)["body_linear_velocities"].start
        control = {}
        for sign in (1.0, -1.0):
            moved = rollout.next_obs.clone()
            moved[..., pelvis : pelvis + 2] = sign * reward.heading_speed * rollout.next_task
            moved[..., pelvis + 2] = 0.0
            r = dataclasses.replace(rollout, next_obs=moved)
            inputs = trainer.objective.discriminator_inputs(r)
            control[sign] = trainer.objective.rewards(r, inputs, trainer.iteration)["control"]
        against = np.exp(-reward.heading_scale * (2 * reward.heading_speed) ** 2)
        torch.testing.assert_close(control[1.0], torch.ones_like(control[1.0]))
        torch.testing.assert_close(control[-1.0], torch.full_like(control[-1.0], against))
        assert against < 0.5
    finally:
        trainer.close()


def test_discriminators_are_judged_on_held_out_demonstrations_and_fresh_samples(demos):
    """Beside the training accuracies (on the minibatch each discriminator just trained on):
    each one's accuracy and mean D on this iteration's fresh policy samples, and, where the
    dataset holds them out, on held-out demonstrations. Judging draws no random number, so the
    run is the same with or without held-out data."""
    # Held out: the punch's second half (a stand-in for a validation split).
    held = tuple(x[len(x) // 2 :] for x in (demos.motion, *demos.interaction))
    judged_run = Trainer(TINY, dataclasses.replace(demos, held_out=held))
    plain_run = Trainer(TINY, demos)
    try:
        judged, plain = judged_run.iterate(), plain_run.iterate()
        after = parameters(judged_run), parameters(plain_run)
    finally:
        judged_run.close()
        plain_run.close()
    for name in ("motion", "interaction0", "interaction1"):
        for metric in ("fresh_accuracy_fake", "held_out_accuracy_real"):
            assert 0 <= judged[f"{name}_{metric}"] <= 1, (name, metric)
        for metric in ("fresh_d", "held_out_d"):
            assert 0 < judged[f"{name}_{metric}"] < 1, (name, metric)
        assert f"{name}_held_out_d" not in plain and f"{name}_fresh_d" in plain
        assert judged[f"{name}_fresh_d"] == plain[f"{name}_fresh_d"]
    assert torch.equal(*after)
