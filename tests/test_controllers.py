"""A controller that is not MAAIP's, end to end (tasks.opponent): the motion tracker replaying
DeepMimic's walk is evaluated in a bout, exported, loaded and checked as any opponent folder
(and its broken folders refused in one line), sparred and served over a WebSocket.

The tracker is tiny and trained two iterations, so it does not walk the clip: started at rest in
the clip's first pose it does not keep up with the clip's pelvis. What it does is move its
limbs as the clip does (the PD targets are the clip's next frame plus its small correction):
the measure here is the pose, each body relative to the pelvis in the pelvis's heading frame,
against the clip's frame of the same step; a fighter holding the first pose (the still guard)
drifts from it as the clip swings its arms and legs."""

from __future__ import annotations

import asyncio
import json

import mujoco
import numpy as np
import pytest
import torch
from opponents import (
    TRACK,
    broken_copy,
    refused,
    served_states,
    spar_server,
    spar_without_torch,
    walk_tracker,
)
from scipy.spatial.transform import Rotation

from models.arena.controller import Seen
from models.arena.mjcf import arena_mjcf
from models.arena.starts import ReferenceMotions
from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import NUM_ACTUATED, NV, heading_frame_of_matrix
from models.humanoid.observations import OBSERVATION_DIM
from models.maaip.networks import Policy
from models.tracking.task import TRACK_OBSERVATION_DIM
from storage.files import sha256_file
from tasks.deepmimic import clip_path, load_deepmimic, retarget
from tasks.errors import BadInput
from tasks.evaluate.bouts import simulate
from tasks.opponent.export import TrainedPolicy, deepmimic_clip, export_tracker, policy_onnx
from tasks.opponent.folder import load_opponent
from tasks.opponent.still import StillGuard
from tasks.opponent.tracker import ClipTracker

BONES = (BoneLengths(), BoneLengths())
STEPS = 12  # policy steps the pose is compared over (0.4 s of the 1.3 s walk)


@pytest.fixture(scope="module")
def walk(assets) -> np.ndarray:
    """DeepMimic's walk on the default body at 30 Hz, (39, 35)."""
    return retarget(load_deepmimic(clip_path(assets, "walk")))


@pytest.fixture(scope="module")
def tracker_policy(walk) -> Policy:
    return walk_tracker(walk)


@pytest.fixture(scope="module")
def folder(tmp_path_factory, tracker_policy, walk):
    facts = {"dataset_key": "none", "run_key": "tracker", "iteration": 2, "metrics": {}}
    return export_tracker(
        tmp_path_factory.mktemp("tracker") / "walk",
        policy=tracker_policy,
        agent=0,
        bones=BONES,
        env=TRACK.env,
        clip=("walk", walk),
        facts=facts,
    )


def pose_error(pos: np.ndarray, pelvis_rot: np.ndarray, clip, frame: int) -> float:
    """Mean distance (m) over the 15 bodies between a fighter's pose (``pos`` (15, 3), its
    pelvis's rotation (3, 3)) and the clip's frame ``frame``, each body relative to its pelvis
    in that pelvis's heading frame (where each stands and faces does not count)."""

    def local(p, rot):
        return (p - p[0]) @ heading_frame_of_matrix(rot)

    mine = local(pos, pelvis_rot)
    theirs = local(clip.states.pos[frame], clip.states.rot[frame, 0])
    return float(np.linalg.norm(mine - theirs, axis=-1).mean())


def test_the_tracker_exports_as_a_folder_of_its_kind(folder, tracker_policy, walk):
    manifest = json.loads((folder / "manifest.json").read_text())
    assert sorted(p.name for p in folder.iterdir()) == [
        "arena.xml",
        "clip.npz",
        "humanoid.xml",
        "manifest.json",
        "policy.onnx",
    ]
    assert manifest["kind"] == "tracker" and manifest["observation"]["size"] == 451
    assert manifest["clip"] == {"name": "walk", "frames": 39, "fps": 30, "file": "clip.npz"}
    opponent = load_opponent(folder)
    assert opponent.kind == "tracker" and isinstance(opponent.controller, ClipTracker)
    assert opponent.agent == 0 and opponent.bones == BONES and opponent.task_dim == 0
    # The bout starts in the clip's first pose; the clip is played as exported.
    np.testing.assert_allclose(opponent.guard[0], walk[0, 7:])
    np.testing.assert_allclose(opponent.controller.clip.qpos, walk)
    # onnxruntime's corrections are torch's, on inputs the normaliser has seen the like of.
    x = torch.randn(16, TRACK_OBSERVATION_DIM, generator=torch.Generator().manual_seed(0))
    x = x * tracker_policy.norm.var.sqrt() + tracker_policy.norm.mean
    with torch.no_grad():
        expected = tracker_policy(x.float(), 0).double().numpy()
    got = opponent.controller.policy(x.numpy().astype(np.float32))
    assert np.abs(got - expected).max() < 1e-5


def test_a_tracker_replaying_the_walk_moves_as_the_clip_in_a_bout(folder, walk):
    """`simulate` takes the loaded tracker as any controller: agent 0 starts at rest in the
    walk's first pose, agent 1 (the rest pose, standing still) 3 m to its side. Measured: the
    tracker's pose stays within 3.8-7.0 cm of the clip's over the first 12 steps; the still guard
    holding the first pose drifts to 17.8 cm by step 12."""
    tracker = load_opponent(folder).controller
    clip = tracker.clip
    q0, q1 = walk[:1].copy(), walk[:1].copy()
    q1[0, 1] += 3.0
    zero = np.zeros((1, NV))
    start = ReferenceMotions(q0, zero, q1, zero, stance=np.stack([walk[0, 7:], np.zeros(28)]))
    model = mujoco.MjModel.from_xml_string(arena_mjcf(BONES, timestep=TRACK.env.timestep))
    data = mujoco.MjData(model)
    errors = {}
    for name, controller in (("tracker", tracker), ("still", StillGuard(walk[0, 7:]))):
        bouts = simulate(
            (controller, StillGuard(np.zeros(NUM_ACTUATED))),
            reference=start,
            bones=BONES,
            env_config=TRACK.env,
            episodes=1,
            frames=2 * STEPS,
            seed=0,
        )
        assert bouts.steps[0] == 2 * STEPS and not bouts.fell.any()
        errors[name] = []
        for t in range(1, STEPS + 1):
            data.qpos[:] = bouts.qpos[0, t]
            mujoco.mj_kinematics(model, data)
            pelvis = data.xmat[1].reshape(3, 3)  # agent 0's 15 bodies are bodies 1-15
            errors[name].append(pose_error(data.xpos[1:16], pelvis, clip, t))
    assert tracker.frames(np.zeros(1, dtype=int))[0] == 2 * STEPS  # a frame a step
    assert max(errors["tracker"]) < 0.09, errors["tracker"]
    assert errors["still"][-1] > 1.8 * errors["tracker"][-1], errors


def test_the_tracker_holds_the_clips_last_frame_after_its_end_and_starts_again_at_a_reset(
    folder,
):
    tracker = load_opponent(folder).controller.fresh()
    clip = tracker.clip
    bodies = clip.states[np.zeros((1, 2), dtype=int)]
    seen = Seen(
        arenas=np.array([3]),
        slot=0,
        bodies=bodies,
        observation=np.zeros((1, OBSERVATION_DIM)),
        partner_observation=np.zeros((1, OBSERVATION_DIM)),
    )
    with pytest.raises(ValueError, match="act before reset"):
        tracker.act(seen)
    tracker.reset(seen)
    actions = [tracker.act(seen) for _ in range(clip.num_frames + 3)]
    assert tracker.frames(np.array([3]))[0] == clip.num_frames - 1
    # Past the end the PD targets are the last frame's (plus the correction of the same input).
    np.testing.assert_array_equal(actions[-1], actions[-2])
    still = StillGuard(clip.qpos[0, 7:])
    assert np.abs(actions[0] - still.act(seen)).max() > 0.05  # it does not hold its guard
    tracker.reset(seen)
    assert tracker.frames(np.array([3]))[0] == 0


def test_broken_tracker_folders_are_refused_in_one_line(tmp_path, folder):
    def broken(name: str, change):
        return broken_copy(tmp_path, folder, name, change)

    def kind(name):
        return lambda _, manifest: manifest.update(kind=name)

    refused(broken("unknown", kind("trackr")), r"manifest.json: kind 'trackr' is not one this")
    # Named MAAIP's, its files are MAAIP's and in order: the 451-input policy is refused.
    refused(
        broken("as_maaip", kind("maaip")),
        r"policy.onnx: takes observations of shape \['batch', 451\]; this Ringside makes "
        r"\(B, 274\)",
    )
    refused(
        broken("no_clip", lambda copy, _: (copy / "clip.npz").unlink()),
        r"clip.npz: missing from the opponent folder",
    )

    def other_clip(copy, manifest):
        np.savez(copy / "clip.npz", qpos=np.zeros((3, 35)), fps=30.0, name="other")

    refused(broken("changed_clip", other_clip), r"clip.npz: does not match the manifest's SHA")

    def maaip_policy(copy, manifest):
        small = Policy(hidden=(8,), action_std=0.1, obs_dim=OBSERVATION_DIM)
        (copy / "policy.onnx").write_bytes(policy_onnx(small, 0))
        manifest["files"]["policy.onnx"] = sha256_file(copy / "policy.onnx")

    refused(
        broken("wrong_size", maaip_policy),
        r"policy.onnx: takes observations of shape \['batch', 274\]; this Ringside makes "
        r"\(B, 451\)",
    )


def test_a_tracker_run_exports_with_the_clip_it_plays(tmp_path, assets, tracker_policy, walk):
    """What `ringside export --run KEY --clip walk` does with a tracker run."""
    run = TrainedPolicy("k" * 64, "d" * 64, 2, TRACK, tracker_policy, BONES, {})
    clip = deepmimic_clip(assets, "walk", BONES[1], fps=TRACK.env.policy_hz)
    np.testing.assert_array_equal(clip, walk)  # the default bones, at the policy's 30 Hz
    opponent = load_opponent(run.export(1, tmp_path / "tracker", ("walk", clip)))
    assert opponent.kind == "tracker" and opponent.agent == 1
    assert opponent.manifest["run_key"] == "k" * 64
    with pytest.raises(ValueError, match="is a tracker: give the clip it plays"):
        run.export(1, tmp_path / "none")
    with pytest.raises(BadInput, match="--clip jog: not one of DeepMimic's clips"):
        deepmimic_clip(assets, "jog", BONES[1], fps=30.0)


def test_a_tracker_spars_against_the_still_partner_without_torch(folder):
    """`ringside spar` on the tracker's folder, in a fresh interpreter: nothing imports torch."""
    result = spar_without_torch(folder)
    assert result["policy_steps"] == 60 and result["timings_s"]["policy"] > 0


def test_a_tracker_is_served_over_a_websocket(folder, tmp_path):
    """One `spar-server` session on the tracker's folder: its states come at a step each, with
    finite bodies, and the served opponent moves as the clip (module docstring). Measured: within
    3.8-8.4 cm of its pose over the first 12 steps, where the clip's pose moves by 17.2 cm from
    step 1 to step 12 (a fighter holding its first pose would end that far from it)."""
    clip = load_opponent(folder).controller.clip
    with spar_server(folder, tmp_path / "data") as served:
        states = asyncio.run(served_states(served.url, STEPS))
    assert [s["step"] for s in states] == list(range(1, STEPS + 1))
    errors = []
    for state in states:
        assert not state["reset"]
        (opponent,) = [f for f in state["fighters"] if f["role"] == "opponent"]
        bodies = np.array(list(opponent["bodies"].values()))  # (15, 7): position, quaternion
        assert bodies.shape == (15, 7) and np.isfinite(bodies).all()
        pelvis = Rotation.from_quat(bodies[0, 3:], scalar_first=True).as_matrix()
        errors.append(pose_error(bodies[:, :3], pelvis, clip, state["step"]))
    assert max(errors) < 0.12, errors
    last = clip.states[STEPS]
    moved = pose_error(last.pos, last.rot[0], clip, 1)
    assert moved > 0.15, moved
