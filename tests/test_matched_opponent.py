"""The matched opponent (tasks.opponent.matched): a tracker playing its fighter's own footage as
the partner-aware motion matcher picks it, exported, loaded, checked, and played.

The footage is DeepMimic's walk with its partner 4 m ahead and DeepMimic's punch with its
partner 0.7 m ahead (as tests/test_matching.py). The tracker is tiny and trained two iterations
on the walk, so where the matcher's choices are the question, the fighter is moved to each frame
it tracks (tracking perfectly) rather than simulated; the bout and `ringside spar` then run it in
MuJoCo."""

from __future__ import annotations

import asyncio
import json

import numpy as np
import pytest
from opponents import (
    TRACK,
    broken_copy,
    facing,
    matched_opponent,
    refused,
    served_states,
    spar_server,
    spar_without_torch,
    walk_punch_footage,
    walk_tracker,
)
from test_matching import turned

from models.arena.controller import Seen
from models.arena.starts import ReferenceMotions
from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import NQ, NV
from models.humanoid.observations import OBSERVATION_DIM, BodyState
from models.humanoid.stance import guard_pose
from models.maaip.networks import Policy
from models.tracking.clips import reference_clip
from models.tracking.matched import MatchedTracker, matched_streams
from models.tracking.matching import MatchConfig, motion_database
from storage.files import sha256_file
from tasks.evaluate.bouts import simulate
from tasks.opponent.export import TrainedPolicy, policy_onnx
from tasks.opponent.folder import load_opponent
from tasks.opponent.still import StillGuard
from tasks.train.config import TrainConfig

BONES = (BoneLengths(), BoneLengths())
FIELDS = tuple(BodyState.__dataclass_fields__)


@pytest.fixture(scope="module")
def footage(assets) -> list[tuple[str, np.ndarray, np.ndarray]]:
    return walk_punch_footage(assets)


@pytest.fixture(scope="module")
def tracker_policy(footage) -> Policy:
    return walk_tracker(footage[0][1])


@pytest.fixture(scope="module")
def folder(tmp_path_factory, tracker_policy, footage):
    return matched_opponent(
        tmp_path_factory.mktemp("matched") / "walk-punch",
        footage,
        tracker_policy,
        MatchConfig(search_every=3, blend_steps=4),
    )


def pair(me: BodyState, partner: BodyState) -> BodyState:
    """(B, 2) states of fighter ``me`` (B,) in slot 0 and its partner (B,) in slot 1."""
    return BodyState(*(np.stack([getattr(me, f), getattr(partner, f)], 1) for f in FIELDS))


def seen(me: BodyState, partner: BodyState) -> Seen:
    zeros = np.zeros((len(me.pos), OBSERVATION_DIM))
    return Seen(np.arange(len(me.pos)), 0, pair(me, partner), zeros, zeros)


def partner_of(controller: MatchedTracker, clip: int, me: BodyState) -> BodyState:
    """Clip ``clip``'s partner (the walk's 4 m ahead, the punch's 0.7 m, facing the fighter)
    placed as it stands to that clip's first frame, about each of fighters ``me`` (B,)."""
    db = controller.database
    first = db.library.clip.states[db.library.start[clip]]
    partner = db.partner[db.library.start[clip]]
    yaw0 = np.arctan2(first.rot[0, 1, 0], first.rot[0, 0, 0])
    centred = BodyState(
        partner.pos - first.pos[0] * [1, 1, 0], partner.rot, partner.lin_vel, partner.ang_vel
    )
    placed = [
        turned(centred, np.arctan2(r[1, 0], r[0, 0]) - yaw0, p * [1, 1, 0])
        for r, p in zip(me.rot[:, 0], me.pos[:, 0], strict=True)
    ]
    return BodyState(*(np.stack([getattr(p, f) for p in placed]) for f in FIELDS))


def played_on(controller: MatchedTracker, me: BodyState, clip: int, steps: int) -> list[int]:
    """``steps`` policy steps of ``controller`` tracking perfectly (the fighter reaches each
    frame it tracks) with clip ``clip``'s partner kept where it stands to that clip; the
    database frame it is at after each."""
    played = []
    for _ in range(steps):
        ahead = controller.reference(np.array([0]))
        controller.act(seen(me, partner_of(controller, clip, me)))
        played.append(int(controller.frames(np.array([0]))[0]))
        me = ahead
    return played


class Recorded:
    """A controller as it is, the database frame it is at after each step written down."""

    def __init__(self, inner: MatchedTracker):
        self.inner, self.played = inner, []

    def reset(self, seen: Seen) -> None:
        self.inner.reset(seen)

    def act(self, seen: Seen) -> np.ndarray:
        actions = self.inner.act(seen)
        self.played.append(int(self.inner.frames(seen.arenas)[0]))
        return actions

    def fresh(self) -> Recorded:
        return self


def test_the_matched_opponent_exports_as_a_folder_of_its_kind(folder, footage):
    manifest = json.loads((folder / "manifest.json").read_text())
    assert sorted(p.name for p in folder.iterdir()) == [
        "arena.xml",
        "humanoid.xml",
        "manifest.json",
        "motion.npz",
        "policy.onnx",
    ]
    assert manifest["kind"] == "matched" and manifest["observation"]["size"] == 451
    assert manifest["motion"] == {
        "source": "footage",
        "clips": 2,
        "frames": 39 + 65,
        "fps": 30,
        "file": "motion.npz",
    }
    assert manifest["matcher"]["search_every"] == 3 and manifest["matcher"]["blend_steps"] == 4
    opponent = load_opponent(folder)
    controller = opponent.controller
    assert opponent.kind == "matched" and isinstance(controller, MatchedTracker)
    assert controller.config == MatchConfig(search_every=3, blend_steps=4)
    np.testing.assert_allclose(controller.database.library.clip.qpos[:39], footage[0][1])
    # A bout starts in the fighter's guard from the footage it plays, not a frame of it.
    frames = np.concatenate([qpos for _, qpos, _ in footage])
    np.testing.assert_allclose(opponent.guard[0], guard_pose(BONES[0], frames))
    assert np.abs(opponent.guard[0] - footage[0][1][0, 7:]).max() > 0.1


def test_it_plays_its_footage_on_and_never_holds_a_clips_end(folder):
    """Tracking perfectly with its partner kept 4 m ahead, the walker walks on for 4 s: always
    frames of the walk (the footage's own answer to a far partner), never a clip's last frame,
    mostly frame after frame."""
    controller = load_opponent(folder).controller.fresh()
    lib = controller.database.library
    me = lib.clip.states[np.array([0])]
    controller.reset(seen(me, partner_of(controller, 0, me)))
    played = played_on(controller, me, clip=0, steps=120)
    clips, _ = lib.locate(np.array(played))
    assert (clips == 0).all(), played
    assert not lib.at_end(np.array(played)).any()
    assert controller.counts.switches >= 120 // 39  # the 1.3 s walk played on again from its frames
    assert (np.diff(played) == 1).mean() > 0.8, played


def test_with_its_partner_stepping_into_reach_it_turns_to_the_punch(folder):
    controller = load_opponent(folder).controller.fresh()
    lib = controller.database.library
    me = lib.clip.states[np.array([0])]
    controller.reset(seen(me, partner_of(controller, 0, me)))
    before = played_on(controller, me, clip=0, steps=6)
    assert (lib.locate(np.array(before))[0] == 0).all()
    me = controller.reference(np.array([0]))
    after = played_on(controller, me, clip=1, steps=controller.config.search_every + 1)
    assert lib.locate(np.array(after[-1:]))[0][0] == 1, after
    # The punch is laid where the body stands, facing its way.
    ref = controller.reference(np.array([0]))
    assert np.linalg.norm((ref.pos[0, 0] - me.pos[0, 0])[:2]) < 0.3


def test_a_motion_strayed_from_the_body_is_moved_back_under_it(folder):
    controller = load_opponent(folder).controller.fresh()
    lib = controller.database.library
    me = lib.clip.states[np.array([0])]
    far = controller.database.partner[np.array([0])]
    controller.reset(seen(me, far))
    pushed = BodyState(me.pos + [0.0, 1.0, 0.0], me.rot, me.lin_vel, me.ang_vel)
    controller.act(seen(pushed, far))
    # The step after the push: the tracked frame lies within the anchor of the pushed pelvis.
    ref = controller.reference(np.array([0]))
    assert np.linalg.norm((ref.pos[0, 0] - pushed.pos[0, 0])[:2]) <= controller.config.anchor_m


def test_a_bout_runs_it_in_mujoco_and_it_punches_with_its_partner_in_reach(folder, footage):
    """`simulate` takes the loaded matched opponent as any controller: 1 s from the walk's first
    pose, the partner standing 4 m ahead, then 0.7 m ahead. With the partner in reach it plays
    the punch's frames, with the partner far the walk's."""
    walk = footage[0][1]
    shares = {}
    for name, gap in (("far", 4.0), ("near", 0.7)):
        recorded = Recorded(load_opponent(folder).controller.fresh())
        q1 = facing(walk, gap)[:1]
        zero = np.zeros((1, NV))
        stance = np.stack([walk[0, 7:], q1[0, 7:]])
        start = ReferenceMotions(walk[:1].copy(), zero, q1, zero, stance=stance)
        bouts = simulate(
            (recorded, StillGuard(q1[0, 7:])),
            reference=start,
            bones=BONES,
            env_config=TRACK.env,
            episodes=1,
            frames=30,
            seed=0,
        )
        assert np.isfinite(bouts.qpos[0, : bouts.steps[0] + 1]).all() and bouts.steps[0] >= 10
        clips, _ = recorded.inner.database.library.locate(np.array(recorded.played))
        shares[name] = float((clips == 1).mean())
    # Measured: 0 % of the steps from the punch with the partner far, 100 % with it near.
    assert shares["far"] <= 0.2 and shares["near"] >= 0.8, shares


def test_broken_matched_folders_are_refused_in_one_line(tmp_path, folder):
    def broken(name: str, change):
        return broken_copy(tmp_path, folder, name, change)

    refused(
        broken("no_motion", lambda copy, _: (copy / "motion.npz").unlink()),
        r"motion.npz: missing from the opponent folder",
    )

    def rewritten(**arrays):
        def change(copy, manifest):
            with np.load(copy / "motion.npz") as stored:
                np.savez(copy / "motion.npz", **{**dict(stored), **arrays})
            manifest["files"]["motion.npz"] = sha256_file(copy / "motion.npz")

        return change

    refused(
        broken("other_body", rewritten(qpos=np.zeros((104, NQ + 3)))),
        r"motion.npz: qpos and partner_qpos must both be \(F, 35\), got \(104, 38\)",
    )
    refused(
        broken("cut_wrong", rewritten(lengths=np.array([39, 60]))),
        r"motion.npz: lengths \[39, 60\] do not cut 104 frames",
    )
    refused(
        broken("other_rate", rewritten(fps=np.float64(60.0))),
        r"motion.npz: motion at 60 fps; the policy steps at 30 Hz",
    )

    def settings(copy, manifest):
        manifest["matcher"]["weights"]["elbows"] = 1.0

    refused(broken("bad_settings", settings), r"manifest.json: matcher settings unreadable")

    def maaip_policy(copy, manifest):
        small = Policy(hidden=(8,), action_std=0.1, obs_dim=OBSERVATION_DIM)
        (copy / "policy.onnx").write_bytes(policy_onnx(small, 0))
        manifest["files"]["policy.onnx"] = sha256_file(copy / "policy.onnx")

    refused(
        broken("maaip_policy", maaip_policy),
        r"policy.onnx: takes observations of shape \['batch', 274\]; this Ringside makes "
        r"\(B, 451\)",
    )


def test_a_tracker_run_exports_as_the_matched_opponent(tmp_path, tracker_policy, footage):
    """What `ringside export --run KEY --matched` does once it has the run's footage."""
    from tasks.opponent.export import MatchedFootage

    run = TrainedPolicy("k" * 64, "d" * 64, 2, TRACK, tracker_policy, BONES, {})
    played = MatchedFootage(tuple(footage), ("left@0",))
    opponent = load_opponent(run.export(0, tmp_path / "matched", footage=played))
    assert opponent.kind == "matched" and opponent.manifest["left_out"] == ["left@0"]
    with pytest.raises(ValueError, match="only a tracker plays footage"):
        TrainedPolicy("m" * 64, "d" * 64, 2, TrainConfig(), tracker_policy, BONES, {}).export(
            0, tmp_path / "none", footage=played
        )


def test_the_matched_opponent_spars_without_torch(folder):
    """`ringside spar` on the matched folder, in a fresh interpreter: nothing imports torch."""
    result = spar_without_torch(folder)
    assert result["policy_steps"] == 60 and result["timings_s"]["policy"] > 0


def test_the_matched_opponent_is_served_over_a_websocket(folder, tmp_path):
    """One `spar-server` session on the matched folder: a state a step, finite bodies."""
    with spar_server(folder, tmp_path / "data") as served:
        states = asyncio.run(served_states(served.url, 30))
    assert [s["step"] for s in states] == list(range(1, 31))
    for state in states:
        (opponent,) = [f for f in state["fighters"] if f["role"] == "opponent"]
        bodies = np.array(list(opponent["bodies"].values()))
        assert bodies.shape == (15, 7) and np.isfinite(bodies).all()


def _two_databases(footage, config: MatchConfig | None = None):
    """The walk-and-punch fighter's database and its partners' (each the other's partner)."""
    own = [reference_clip(n, q, BONES[0], fps=30.0) for n, q, _ in footage]
    others = [reference_clip(f"{n}:partner", p, BONES[1], fps=30.0) for n, _, p in footage]
    return (
        motion_database(own, others, fps=30.0, config=config),
        motion_database(others, own, fps=30.0, config=config),
    )


def test_matched_streams_stitch_the_footage_into_long_motion_without_cuts(footage):
    """DReCon's training streams: 10 s of each fighter, against clips of 1.3 s and 2.2 s, so
    they are made of transitions; each is laid where the motion left off (the pelvis never
    jumps) and cross-faded (no hinge moves faster than in the footage: without the fade, cuts
    move one by 1.7 rad in a frame)."""
    count, frames = 6, 300
    streams = matched_streams(
        _two_databases(footage), count=count, frames=frames, rng=np.random.default_rng(0)
    )
    assert [s.shape for s in streams] == [(count, frames, NQ)] * 2
    assert max(len(q) for _, q, _ in footage) < frames / 4
    own = streams[0]
    step = np.linalg.norm(np.diff(own[:, :, :2], axis=1), axis=-1)
    assert step.max() < 0.15  # 4.5 m/s; the walk's own steps are up to 0.045 m
    fastest = max(np.abs(np.diff(q[:, 7:], axis=0)).max() for _, q, _ in footage)
    assert np.abs(np.diff(own[:, :, 7:], axis=1)).max() <= fastest + 1e-6
    cut = matched_streams(
        _two_databases(footage, MatchConfig(blend_steps=0)),
        count=count,
        frames=frames,
        rng=np.random.default_rng(0),
    )[0]
    assert np.abs(np.diff(cut[:, :, 7:], axis=1)).max() > fastest + 0.5
    # Both of the fighter's clips are played in every stream, and the streams differ.
    db = _two_databases(footage)[0]
    poses = db.library.clip.qpos[:, 7:]
    nearest = np.argmin(
        np.abs(own[:, :, None, 7:] - poses[None, None]).max(-1), axis=-1
    )  # (count, frames) the nearest footage frame by the largest hinge gap
    clip_of, _ = db.library.locate(nearest)
    assert all(set(np.unique(c)) == {0, 1} for c in clip_of)
    assert not np.allclose(own[0], own[1])
    again = matched_streams(
        _two_databases(footage), count=count, frames=frames, rng=np.random.default_rng(0)
    )
    np.testing.assert_array_equal(again[0], own)


def test_a_tracker_trains_on_matched_streams_beside_its_footage(footage):
    """`train.track.matched_streams` adds the streams to the train clips of both agents (the
    gate and the clips' tracking stay on the footage: `tasks.train.run`)."""
    from dataclasses import replace

    from models.tracking.clips import tracking_data
    from tasks.errors import BadInput
    from tasks.train.tracker import with_streams

    qpos = ({n: q for n, q, _ in footage}, {n: p for n, _, p in footage})
    data = tracking_data(qpos, BONES, fps=30.0, key="clips:walk,punch")
    config = replace(TRACK, track=replace(TRACK.track, matched_streams=3, matched_stream_s=4.0))
    made = with_streams(data, config)
    assert [[c.name for c in clips] for clips in made.clips] == [
        ["walk", "punch", "stream:0", "stream:1", "stream:2"]
    ] * 2
    assert all(c.num_frames == 120 for clips in made.clips for c in clips[2:])
    assert with_streams(data, TRACK) is data
    short = tracking_data(
        ({n: q[:20] for n, q, _ in footage}, {n: p[:20] for n, _, p in footage}),
        BONES,
        fps=30.0,
        key="short",
    )
    with pytest.raises(BadInput, match="matched_streams: no clip is longer"):
        with_streams(short, config)
    with pytest.raises(ValueError, match="matched_streams must be >= 0"):
        replace(TRACK.track, matched_streams=-1)


def test_the_evaluation_matches_both_fighters_from_their_own_footage(
    tmp_path, tracker_policy, footage
):
    """The evaluate stage's matched pair (`tasks.evaluate.stage.matched_pair`): the tracker's
    torch policy playing each fighter's own footage, as `simulate` runs any pair; the same
    actions as the exported ONNX opponent's, and a bout that runs."""
    from tasks.evaluate.stage import matched_pair
    from tasks.opponent.export import MatchedFootage

    run = TrainedPolicy("k" * 64, "d" * 64, 2, TRACK, tracker_policy, BONES, {})
    mine = MatchedFootage(tuple(footage), ())
    theirs = MatchedFootage(tuple((n, other, own) for n, own, other in footage), ())
    pair = matched_pair(run, (mine, theirs))
    # Each plays its own fighter's footage: agent 1's database holds the partners' frames.
    for agent, played in enumerate((mine, theirs)):
        library = pair[agent].database.library
        assert library.num_clips == 2
        np.testing.assert_allclose(library.clip.qpos[: len(played.clips[0][1])], played.clips[0][1])
    observation = np.random.default_rng(0).normal(size=(3, 451)).astype(np.float32)
    onnx = load_opponent(run.export(0, tmp_path / "matched", footage=mine)).controller
    np.testing.assert_allclose(pair[0].policy(observation), onnx.policy(observation), atol=1e-5)
    walk = footage[0][1]
    q1 = facing(walk, 1.5)[:1]
    zero = np.zeros((1, NV))
    start = ReferenceMotions(
        walk[:1].copy(), zero, q1, zero, stance=np.stack([walk[0, 7:], q1[0, 7:]])
    )
    bouts = simulate(
        pair, reference=start, bones=BONES, env_config=TRACK.env, episodes=2, frames=20, seed=0
    )
    assert (bouts.steps >= 5).all() and np.isfinite(bouts.qpos[0, : bouts.frames[0]]).all()


def test_the_evaluation_never_matches_from_held_out_footage():
    """`held_out_overlap` names the matched clips that share a step with a held-out clip."""
    from tasks.dataset.store import FootageClip
    from tasks.evaluate.stage import held_out_overlap
    from tasks.opponent.export import MatchedFootage

    q = np.zeros((30, NQ))
    heldout = (FootageClip("v" * 16, q, q, BoneLengths(), start_step=100),)
    video = "v" * 12
    apart = MatchedFootage(
        ((f"{video}@40", q, q), (f"{video}@130", q, q), (f"w{video[1:]}@100", q, q)), ()
    )
    assert held_out_overlap((apart,), heldout) == []
    touching = MatchedFootage(((f"{video}@71", q, q), (f"{video}@129", q, q)), ())
    assert held_out_overlap((apart, touching), heldout) == [f"{video}@71", f"{video}@129"]
