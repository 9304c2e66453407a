"""The exported opponent (tasks.opponent.export, .folder, .spar): ONNX parity with torch on
recorded observations, the folder's contents, clear errors for bad folders, and sparring."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from conftest import read_video, run_cli
from test_standing import sample_fighters

from models.arena.config import EnvConfig
from models.humanoid.boxer import BoneLengths
from models.humanoid.observations import OBSERVATION_DIM
from models.humanoid.stance import guard_pose
from models.maaip.config import DiscriminatorConfig, NetworkConfig, PPOConfig
from models.maaip.networks import Policy, make_networks
from models.maaip.trainer import Trainer
from storage.files import sha256_file
from tasks.errors import BadInput
from tasks.opponent.export import export_opponent, onnx_max_abs_diff, policy_onnx
from tasks.opponent.folder import load_opponent
from tasks.opponent.maaip import OnnxPolicy
from tasks.opponent.spar import spar
from tasks.train.config import TrainConfig
from tasks.train.data import clip_demonstrations

REPO = Path(__file__).resolve().parent.parent
ARTIFACTS = REPO / "data" / "test-artifacts" / "spar"
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
    exported = opponent.controller
    assert opponent.kind == "maaip" and isinstance(exported, OnnxPolicy)
    recorded = obs[:, :, agent].reshape(-1, OBSERVATION_DIM)
    assert len(recorded) == 64
    assert policy.norm.count > 0  # the normaliser is part of the export, and not the identity
    assert onnx_max_abs_diff(policy, agent, exported, recorded) < 1e-5
    assert onnx_max_abs_diff(policy, agent, exported, recorded[:1]) < 1e-5  # any batch size
    # The two agents' exports differ: the agent id is baked in.
    other = policy(torch.from_numpy(recorded[:4]), 1 - agent).detach().numpy()
    assert np.abs(exported.actions(recorded[:4]) - other).max() > 1e-4
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
    assert manifest["format"] == 2 and manifest["kind"] == "maaip"
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
    manifest["files"]["policy.onnx"] = sha256_file(other / "policy.onnx")
    (other / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(
        BadInput, match=r"policy.onnx: takes observations of shape \['batch', 100\]"
    ):
        load_opponent(other)
    # A kind this Ringside does not know.
    unknown = broken("unknown_kind")
    manifest = json.loads((unknown / "manifest.json").read_text())
    manifest["kind"] = "motion_matcher"
    (unknown / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BadInput, match=r"manifest.json: kind 'motion_matcher' is not one this"):
        load_opponent(unknown)


def test_a_folder_written_before_the_kinds_loads_as_maaips(tmp_path, trained):
    """Format 1 named no kind: it held MAAIP's policy, and still loads as that."""
    policy, bones, obs = trained
    folder = _export(tmp_path, policy, bones)
    manifest = json.loads((folder / "manifest.json").read_text())
    del manifest["kind"]
    manifest["format"] = 1
    (folder / "manifest.json").write_text(json.dumps(manifest))
    opponent = load_opponent(folder)
    recorded = obs[:, :, 0].reshape(-1, OBSERVATION_DIM)
    assert opponent.kind == "maaip"
    assert onnx_max_abs_diff(policy, 0, opponent.controller, recorded) < 1e-5
    manifest["format"] = 3
    (folder / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BadInput, match=r"manifest.json: format 3; this Ringside reads formats 1"):
        load_opponent(folder)


# ---------------------------------------------------------------- sparring


@pytest.fixture(scope="module")
def pair(tmp_path_factory, trained):
    """Both fighters of the trained run as opponent folders."""
    policy, bones, _ = trained
    root = tmp_path_factory.mktemp("pair")
    return [_export(root, policy, bones, agent) for agent in (0, 1)]


def test_spar_runs_a_minute_against_the_trained_partner_without_torch(pair):
    # A fresh interpreter, so that nothing else has imported torch: the runtime must not.
    code = (
        "import json, sys; from pathlib import Path; from flows.cli import main; "
        f"rc = main(['spar', '{pair[0]}', '--partner', '{pair[1]}', '--seconds', '60', "
        "'--json']); assert 'torch' not in sys.modules, 'torch was imported'; sys.exit(rc)"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=600
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.strip().splitlines()
    result = json.loads(lines[0])
    assert result["simulated_s"] == 60.0 and result["policy_steps"] == 1800
    assert result["realtime_factor"] > 0 and result["timings_s"]["physics"] > 0
    assert lines[-1] == f"realtime_factor: {result['realtime_factor']:.1f} x"


def test_spar_renders_a_bout_that_plays(tmp_path, pair):
    video = tmp_path / "bout.mp4"
    opponent = load_opponent(pair[0])
    result = spar(opponent, None, seconds=2.0, video=video, size=(320, 180))
    assert result.frames_rendered == 60
    _, frames = read_video(video)
    assert len(frames) == 60 and frames[0].shape == (180, 320, 3)
    # The fighters are on screen: the middle of the picture differs from its empty edges, and
    # they move: every fifth of a second the picture has changed from the first (by 0.17-0.31
    # of 255 on average for this tiny run's fighters, which sway in their guard; 0 if frozen).
    first = frames[0].astype(float)
    assert first[:, 120:200].std() > first[:, :40].std() + 5
    assert min(np.abs(f.astype(float) - first).mean() for f in frames[6::6]) > 0.1
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    for index in (0, 30, 59):
        cv2.imwrite(str(ARTIFACTS / f"bout_{index:02d}.png"), frames[index])


def test_spar_refuses_bad_folders(capsys, tmp_path, pair):
    code, _, err = run_cli(capsys, "spar", str(tmp_path / "nothing"))
    assert code == 2 and "no such opponent folder" in err
    code, _, err = run_cli(capsys, "spar", str(pair[0]), "--partner", str(tmp_path))
    assert code == 2 and "manifest.json: missing" in err
    # A caller that needs one kind (the matched opponent's benchmarks) is told the folder's.
    with pytest.raises(BadInput, match="of kind 'maaip', not 'matched'") as refused:
        load_opponent(pair[0], kind="matched")
    assert str(pair[0] / "manifest.json") in str(refused.value)


def test_an_opponent_starts_in_its_guard_and_stands_against_a_still_partner(tmp_path, sample_run):
    """The folder carries each fighter's guard and a bout starts in it: an untrained policy,
    whose mean is its guard, stands a minute against a partner holding its guard. (Started
    in the rest pose, straight-legged, the demo's trained opponent fell 12 times in 20 s.)"""
    fighters = sample_fighters(sample_run)
    bones = (fighters[0].bones, fighters[1].bones)
    stance = np.stack([guard_pose(f.bones, f.qpos) for f in fighters])
    nets = make_networks(SMALL, generator=torch.Generator().manual_seed(0), stance=stance)
    folder = _export(tmp_path, nets.policy.eval(), bones)
    opponent = load_opponent(folder)
    assert np.allclose(opponent.guard, stance, atol=1e-6)
    result = spar(opponent, None, seconds=60)
    assert result.falls == (0, 0), result.falls

    # An outside hand (`spar`'s forces): half its weight sideways on its pelvis, every step,
    # pushes over the fighter that stood the minute; its partner, untouched, stays up.
    calls = []

    def shove(env, bodies):
        calls.append(bodies.pos.shape)
        agent = env.index.agents[opponent.agent]
        forces = np.zeros((1, env.model.nbody, 6))
        forces[0, agent.body_ids[0], 1] = 0.5 * 9.81 * env.model.body_mass[agent.body_ids].sum()
        return forces

    shoved = spar(opponent, None, seconds=10, forces=shove)
    assert len(calls) == shoved.policy_steps and calls[0][:2] == (1, 2)
    assert shoved.falls[0] > 0 and shoved.falls[1] == 0, shoved.falls
