"""MAAIP from the tracker (models.maaip.distill, `train.distill`): the two fighters of one piece
of footage started as filmed, and a MAAIP policy fitted to a tracker's actions (DART, DAgger)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from models.arena.env import ArenaEnv
from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import NUM_ACTUATED
from models.maaip.config import (
    DistillConfig,
    EnvConfig,
    NetworkConfig,
    PPOConfig,
)
from models.maaip.distill import distill
from models.maaip.networks import make_networks
from models.maaip.objectives import tracking_networks
from models.tracking.clips import TrackingData, tracking_data
from models.tracking.config import TrackConfig
from models.tracking.task import Tracker
from tasks.deepmimic import clip_path, load_deepmimic, retarget
from tasks.train.config import TrainConfig

BONES = (BoneLengths(), BoneLengths())
CONFIG = TrainConfig(
    seed=3,
    network=NetworkConfig(hidden="64,64"),
    env=EnvConfig(num_envs=8, threads=1, stepping="threads"),
    ppo=PPOConfig(minibatch_size=256),
    distill=DistillConfig(rounds=3, steps=30, epochs=30, minibatch_size=256),
)


@pytest.fixture(scope="module")
def footage(assets) -> TrackingData:
    """Two fighters of one 'piece of footage': DeepMimic's walk, and the same walk 1.5 m to its
    side (so the bodies never meet), paired clip by clip."""
    walk = retarget(load_deepmimic(clip_path(assets, "walk")))
    beside = walk.copy()
    beside[:, 1] += 1.5
    return tracking_data(({"walk": walk}, {"walk": beside}), BONES, fps=30.0, key="filmed")


def test_as_filmed_both_fighters_start_on_one_frame_where_the_footage_has_them(footage):
    config = EnvConfig(num_envs=6, threads=1, stepping="threads")
    with ArenaEnv(config, np.random.default_rng(0)) as env:
        tracker = Tracker(footage, TrackConfig(), config)
        tracker.reset(env, np.arange(6), np.random.default_rng(4), as_filmed=True)
        flat = tracker.flat
        assert np.array_equal(flat[:, 0], flat[:, 1]) and len(np.unique(flat[:, 0])) > 1
        states = env.body_states()
        for a in (0, 1):
            reference = footage.clips[a][0].states[flat[:, a]]
            np.testing.assert_allclose(states.pos[:, a], reference.pos, atol=1e-6)
        # Clips that do not pair up (other lengths) cannot be started as filmed.
        short = tracking_data(
            ({"walk": footage.clips[0][0].qpos}, {"walk": footage.clips[1][0].qpos[:-5]}),
            BONES,
            fps=30.0,
            key="unpaired",
        )
        with pytest.raises(ValueError, match="pair up"):
            Tracker(short, TrackConfig(), config).reset(
                env, np.arange(6), np.random.default_rng(4), as_filmed=True
            )


def _labelled(footage: TrackingData, teacher, seed: int) -> tuple[torch.Tensor, ...]:
    """States of the footage played by the tracker (as filmed, from random frames), each with
    MAAIP's observation of it and the tracker's action there: data no fit has seen."""
    n = 8
    config = EnvConfig(num_envs=n, threads=1, stepping="threads")
    agents = torch.arange(2).repeat(n)
    obs, labels = [], []
    with ArenaEnv(config, np.random.default_rng(seed)) as env:
        tracker = Tracker(footage, TrackConfig(), config)
        told = tracker.reset(env, np.arange(n), np.random.default_rng(seed), as_filmed=True)
        for _ in range(10):
            held = tracker.actions(np.zeros((n, 2, NUM_ACTUATED)))
            x = torch.as_tensor(told, dtype=torch.float32).reshape(2 * n, -1)
            correction, _ = teacher.act(x, agents, deterministic=True)
            label = held + correction.reshape(n, 2, -1).double().numpy()
            obs.append(torch.as_tensor(env.observe(), dtype=torch.float32).reshape(2 * n, -1))
            labels.append(torch.as_tensor(label, dtype=torch.float32).reshape(2 * n, -1))
            step = tracker.step(env, label - held)
            told = step.observation
            done = np.flatnonzero(step.done)
            if done.size:
                told = told.copy()
                told[done] = tracker.reset(
                    env, done, np.random.default_rng(seed + 1), as_filmed=True
                )
    return torch.cat(obs), agents.repeat(len(obs)), torch.cat(labels)


def test_the_distilled_policy_acts_as_the_tracker_on_states_it_never_saw(footage):
    # The teacher: an untrained tracker, which plays the clips back through the PD controllers
    # (its corrections start near zero): a known, non-trivial state-to-action map.
    teacher, _ = tracking_networks(CONFIG, generator=torch.Generator().manual_seed(1))
    teacher.eval()

    def student():
        return make_networks(CONFIG, generator=torch.Generator().manual_seed(2)).policy

    obs, agents, labels = _labelled(footage, teacher, seed=11)
    untrained = student()
    with torch.no_grad():
        before = float((untrained(obs, agents) - labels).square().mean())

    def distilled():
        taught = student()
        rounds = distill(
            taught,
            teacher,
            footage,
            CONFIG,
            generator=torch.Generator().manual_seed(0),
            rng=np.random.default_rng(0),
        )
        return taught, rounds

    taught, rounds = distilled()
    with torch.no_grad():
        after = float((taught(obs, agents) - labels).square().mean())
    # Held-out states: the fit carries over to states none of the rounds visited.
    assert after < 0.1 * before, (before, after)
    assert [r["round"] for r in rounds] == [0.0, 1.0, 2.0]
    # Every round adds each arena's steps for both agents, and refits on all of them.
    assert [r["samples"] for r in rounds] == [2 * 8 * 30 * (k + 1) for k in range(3)]
    assert all(r["loss"] < before and r["episode_s"] > 0 for r in rounds)

    # A seed means one result.
    again, _ = distilled()
    for mine, theirs in zip(taught.state_dict().values(), again.state_dict().values(), strict=True):
        assert torch.equal(mine, theirs)


def test_distilling_is_for_maaip_without_a_heading_target():
    with pytest.raises(ValueError, match="from_tracker"):
        dataclasses.replace(CONFIG, objective="track", distill=DistillConfig(from_tracker=True))
    for bad in ({"rounds": 0}, {"noise": -0.1}, {"learning_rate": 0.0}):
        with pytest.raises(ValueError, match="train.distill"):
            DistillConfig(**bad)
