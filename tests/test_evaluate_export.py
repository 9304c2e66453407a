"""The exported opponent (tasks.evaluate.export, tasks.evaluate.opponent): ONNX parity with
torch on recorded observations, the folder's contents, and clear errors for bad folders."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from models.humanoid.boxer import BoneLengths
from models.humanoid.observations import OBSERVATION_DIM
from tasks.errors import BadInput
from tasks.evaluate.export import export_opponent, onnx_max_abs_diff, policy_onnx
from tasks.evaluate.opponent import file_digest, load_opponent
from tasks.train.config import (
    DiscriminatorConfig,
    NetworkConfig,
    PPOConfig,
    TrainConfig,
)
from tasks.train.data import clip_demonstrations
from tasks.train.env import EnvConfig
from tasks.train.mappo import Trainer
from tasks.train.networks import Policy

SMALL = TrainConfig(
    network=NetworkConfig(hidden="32,32"),
    discriminator=DiscriminatorConfig(samples_per_update=64, updates_per_iteration=1),
    ppo=PPOConfig(horizon=8, minibatch_size=64, epochs=1, learning_rate=1e-3),
    env=EnvConfig(num_envs=8, threads=1),
)


@pytest.fixture(scope="module")
def trained(assets):
    """A briefly trained policy (its normaliser has seen data) and a rollout's observations."""
    demos = clip_demonstrations(assets, "punch", (BoneLengths(), BoneLengths().scaled(0.9)))
    trainer = Trainer(SMALL, demos)
    try:
        for _ in range(3):
            trainer.iterate()
        rollout = trainer.collect()
    finally:
        trainer.close()
    obs = rollout.obs.numpy()  # (T, N, 2, 274)
    return trainer.nets.policy.eval(), demos.bones, obs


def _export(tmp_path, policy, bones, agent=0):
    facts = {"dataset_key": "d", "run_key": "r", "iteration": 3, "metrics": {}}
    return export_opponent(
        tmp_path / f"opponent{agent}",
        policy=policy,
        agent=agent,
        bones=bones,
        env=SMALL.env,
        facts=facts,
    )


@pytest.mark.parametrize("agent", [0, 1])
def test_onnx_matches_torch_on_recorded_observations(tmp_path, trained, agent):
    policy, bones, obs = trained
    opponent = load_opponent(_export(tmp_path, policy, bones, agent))
    recorded = obs[:, :, agent].reshape(-1, OBSERVATION_DIM)
    assert len(recorded) == 64
    assert policy.norm.count > 0  # the normaliser is part of the export, and not the identity
    assert onnx_max_abs_diff(policy, agent, opponent, recorded) < 1e-5
    assert onnx_max_abs_diff(policy, agent, opponent, recorded[:1]) < 1e-5  # any batch size
    # The two agents' exports differ: the agent id is baked in.
    other = policy(torch.from_numpy(recorded[:4]), 1 - agent).detach().numpy()
    assert np.abs(opponent.act(recorded[:4]) - other).max() > 1e-4
    assert opponent.agent == agent and opponent.bones == bones


def test_the_folder_holds_the_models_and_a_manifest(tmp_path, trained):
    policy, bones, _ = trained
    folder = _export(tmp_path, policy, bones)
    manifest = json.loads((folder / "manifest.json").read_text())
    assert sorted(p.name for p in folder.iterdir()) == [
        "arena.xml",
        "humanoid.xml",
        "manifest.json",
        "policy.onnx",
    ]
    assert manifest["observation"]["size"] == 274 and manifest["action"]["size"] == 28
    assert manifest["run_key"] == "r" and manifest["role"] == "adversary"
    assert "<mujoco" in (folder / "humanoid.xml").read_text()
    assert not folder.with_name(folder.name + ".partial").exists()


def test_bad_opponent_folders_are_refused_with_the_file_named(tmp_path, trained):
    policy, bones, _ = trained
    good = _export(tmp_path, policy, bones)

    def broken(name):
        folder = tmp_path / name
        shutil.copytree(good, folder)
        return folder

    with pytest.raises(BadInput, match="no such opponent folder"):
        load_opponent(tmp_path / "nowhere")
    missing = broken("missing")
    (missing / "humanoid.xml").unlink()
    with pytest.raises(BadInput, match=r"humanoid.xml: missing from the opponent folder"):
        load_opponent(missing)
    changed = broken("changed")
    (changed / "arena.xml").write_text("<mujoco/>")
    with pytest.raises(BadInput, match=r"arena.xml: does not match the manifest's SHA-256"):
        load_opponent(changed)
    garbled = broken("garbled")
    (garbled / "manifest.json").write_text("{not json")
    with pytest.raises(BadInput, match="manifest.json: not valid JSON"):
        load_opponent(garbled)
    # A policy for another observation size, its manifest otherwise in order.
    other = broken("other_size")
    small = Policy(hidden=(8,), action_std=0.1, obs_dim=100)
    (other / "policy.onnx").write_bytes(policy_onnx(small, 0))
    manifest = json.loads((other / "manifest.json").read_text())
    manifest["files"]["policy.onnx"] = file_digest(other / "policy.onnx")
    (other / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(
        BadInput, match=r"policy.onnx: takes observations of shape \['batch', 100\]"
    ):
        load_opponent(other)
