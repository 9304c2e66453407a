"""The tracker (models.tracking, objective 'track'): DeepMimic's reward against
hand-worked values, reference state initialisation, the DReCon residual, early termination,
and a tracking run that resumes exactly."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from training_runs import resumes_exactly

from models.arena.env import ArenaEnv
from models.arena.pushes import random_pushes
from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import axis_angle_matrix
from models.humanoid.observations import BodyState
from models.maaip.config import (
    EnvConfig,
    NetworkConfig,
    PPOConfig,
    RewardConfig,
)
from models.maaip.trainer import Trainer
from models.tracking.clips import TrackingData, tracking_data
from models.tracking.config import TrackConfig
from models.tracking.gate import Gate, gate_held, gate_met, track_gate
from models.tracking.reward import centre_of_mass, deepmimic_reward, rotation_angles
from models.tracking.task import TRACK_OBSERVATION_DIM, Tracker
from tasks.deepmimic import clip_path, load_deepmimic, retarget
from tasks.train.config import TrainConfig
from tasks.train.data import clip_demonstrations

BONES = (BoneLengths(), BoneLengths())
TINY = TrainConfig(
    objective="track",
    seed=5,
    network=NetworkConfig(hidden="32,32"),
    ppo=PPOConfig(horizon=8, minibatch_size=32, epochs=2),
    env=EnvConfig(num_envs=4, threads=1),
)
HEAD, RIGHT_HAND = 2, 5


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def data(assets) -> TrackingData:
    """DeepMimic's walk and punch on the default body, for both agents."""
    clips = {name: retarget(load_deepmimic(clip_path(assets, name))) for name in ("walk", "punch")}
    return tracking_data((clips, clips), BONES, fps=30.0, key="clips:walk,punch")


def _env(num_envs: int) -> ArenaEnv:
    config = EnvConfig(num_envs=num_envs, threads=1, stepping="threads")
    return ArenaEnv(config, np.random.default_rng(0))


def _tracker(data: TrackingData, env: ArenaEnv) -> Tracker:
    return Tracker(data, TrackConfig(), env.config)


def _changed(state: BodyState, **arrays) -> BodyState:
    return dataclasses.replace(state, **arrays)


# ---------------------------------------------------------------- the reward


def test_the_deepmimic_reward_is_one_on_the_reference_and_falls_with_each_error(data):
    config = TrackConfig()
    clip = data.clips[0][1]
    ref, com = clip.states[10:13], clip.com[10:13]
    for value in deepmimic_reward(ref, ref, com, com, config=config).values():
        np.testing.assert_allclose(value, 1.0, atol=1e-12)

    def total(sim: BodyState, sim_com: np.ndarray = com) -> np.ndarray:
        return deepmimic_reward(sim, ref, sim_com, com, config=config)["total"]

    # The head (a leaf: no child joint sees it) turned 0.1 rad: r_p = exp(-2 x 0.1^2).
    rot = ref.rot.copy()
    rot[:, HEAD] = rot[:, HEAD] @ axis_angle_matrix((1.0, 0.0, 0.0), 0.1)
    np.testing.assert_allclose(total(_changed(ref, rot=rot)), 0.65 * np.exp(-0.02) + 0.35)
    # The head spinning 1 rad/s faster: r_v = exp(-0.1 x 1).
    ang = ref.ang_vel.copy()
    ang[:, HEAD, 2] += 1.0
    np.testing.assert_allclose(total(_changed(ref, ang_vel=ang)), 0.1 * np.exp(-0.1) + 0.9)
    # The right hand 10 cm higher: r_e = exp(-40 x 0.1^2).
    pos = ref.pos.copy()
    pos[:, RIGHT_HAND, 2] += 0.1
    np.testing.assert_allclose(total(_changed(ref, pos=pos)), 0.15 * np.exp(-0.4) + 0.85)
    # The centre of mass 20 cm aside: r_c = exp(-10 x 0.2^2).
    np.testing.assert_allclose(total(ref, com + [0, 0.2, 0]), 0.1 * np.exp(-0.4) + 0.9)
    # Larger errors, smaller rewards.
    angles = [0.0, 0.1, 0.3, 1.0]
    rewards = []
    for angle in angles:
        rot = ref.rot.copy()
        rot[:, HEAD] = rot[:, HEAD] @ axis_angle_matrix((0.0, 1.0, 0.0), angle)
        rewards.append(total(_changed(ref, rot=rot))[0])
    assert np.all(np.diff(rewards) < 0)


def test_rotation_angles_are_exact_near_zero():
    for angle in (1e-7, 1e-3, 0.5, 3.0):
        turn = axis_angle_matrix((0.0, 0.6, 0.8), angle)
        assert rotation_angles(np.eye(3), turn) == pytest.approx(angle, rel=1e-9)


# ---------------------------------------------------------------- episodes


def test_rest_starts_put_that_share_of_the_starts_at_rest_on_their_frame(data):
    """`TrackConfig.rest_start_share`: the start frame's pose with no velocity, as a bout
    starts its fighters; the other starts keep the clip's velocities."""
    with _env(64) as env:
        tracker = Tracker(data, TrackConfig(rest_start_share=0.5), env.config)
        tracker.reset(env, np.arange(64), np.random.default_rng(3))
        clip, frame = tracker.clip_and_frame()
        rest = []
        for i, d in enumerate(env.datas):
            agent = env.index.agents[0]
            want = data.clips[0][clip[i, 0]].qpos[frame[i, 0]]
            np.testing.assert_allclose(d.qpos[agent.qpos][2:], want[2:], atol=1e-12)
            rest.append(not d.qvel[agent.qvel].any())
        assert 16 <= sum(rest) <= 48
    with pytest.raises(ValueError, match="rest_start_share must be between 0 and 1"):
        TrackConfig(rest_start_share=1.5)


def test_a_reset_puts_each_agent_on_its_clip_frame_with_the_clips_velocities(data):
    with _env(6) as env:
        tracker = _tracker(data, env)
        obs = tracker.reset(env, np.arange(6), np.random.default_rng(1))
        assert obs.shape == (6, 2, TRACK_OBSERVATION_DIM)
        clip, frame = tracker.clip_and_frame()
        last = np.array([c.num_frames - 1 for c in data.clips[0]])
        assert (frame >= 0).all() and (frame < last[clip]).all()
        states = env.body_states()
        for i, d in enumerate(env.datas):
            for a, agent in enumerate(env.index.agents):
                reference = data.clips[a][clip[i, a]]
                want = reference.qpos[frame[i, a]].copy()
                want[:2] += tracker.offset[i, a, :2]
                np.testing.assert_allclose(d.qpos[agent.qpos], want, atol=1e-12)
                np.testing.assert_allclose(d.qvel[agent.qvel], reference.qvel[frame[i, a]])
                # Each clip starts at its agent's slot, heading kept.
                np.testing.assert_allclose(d.qpos[agent.qpos][:2], tracker.slots[a, :2])
                # Its centre of mass as MuJoCo computes it.
                com = centre_of_mass(states[i, a], reference.body_mass, reference.body_com)
                np.testing.assert_allclose(com, d.subtree_com[agent.body_ids[0]], atol=1e-12)
        ref = tracker.reference(tracker.flat)
        for name in ("pos", "rot", "lin_vel", "ang_vel"):
            np.testing.assert_allclose(getattr(states, name), getattr(ref, name), atol=1e-9)


def test_together_starts_put_both_fighters_at_one_frame_of_one_footage_as_filmed(data):
    """`TrackConfig.together_share`: that share of the starts has both agents at the same frame
    of clip k where the footage has them (here agent 1 is agent 0's clip 1.5 m aside); the
    others start at their slots, each on its own draw."""
    aside = tuple(
        dataclasses.replace(c, qpos=c.qpos + np.r_[0, 1.5, np.zeros(33)]) for c in data.clips[0]
    )
    pair = tracking_data(
        ({c.name: c.qpos for c in data.clips[0]}, {c.name: c.qpos for c in aside}),
        BONES,
        fps=30.0,
        key="clips:walk,punch aside",
    )
    with _env(64) as env:
        tracker = Tracker(pair, TrackConfig(together_share=0.5), env.config)
        tracker.reset(env, np.arange(64), np.random.default_rng(2))
        together = (tracker.flat[:, 0] == tracker.flat[:, 1]) & ~tracker.offset.any(axis=(1, 2))
        assert 16 <= together.sum() <= 48
        for i, d in enumerate(env.datas):
            pelvis = [d.qpos[agent.qpos][:3] for agent in env.index.agents]
            if together[i]:
                np.testing.assert_allclose(pelvis[1] - pelvis[0], [0, 1.5, 0], atol=1e-12)
            else:  # at their slots, 4 m apart along y
                np.testing.assert_allclose(pelvis[0][:2], tracker.slots[0, :2])
                np.testing.assert_allclose(pelvis[1][:2], tracker.slots[1, :2])
        # Clips that do not pair up frame for frame cannot start together.
        short = tracking_data(
            ({c.name: c.qpos for c in data.clips[0]}, {"walk": data.clips[0][0].qpos[:20]}),
            BONES,
            fps=30.0,
            key="unpaired",
        )
        with pytest.raises(ValueError, match="do not pair up"):
            Tracker(short, TrackConfig(together_share=0.5), env.config)


def test_pushes_hit_each_fighter_at_their_rate_with_a_thrown_objects_momentum(data):
    """`TrackConfig.push_every_s`: with a push every 0.2 s on average, each agent is hit in
    about 1 in 6 of the 30 Hz steps, by 1-10 kg at 5 m/s (150-1500 N for a step), horizontally,
    on one of its own bodies; a tracker given no generator (the gate's) is never pushed."""
    config = TrackConfig(push_every_s=0.2)
    with _env(32) as env:
        body_ids = np.stack([agent.body_ids for agent in env.index.agents])
        rng = np.random.default_rng(4)
        hits = []
        for _ in range(20):
            pushes = random_pushes(
                rng,
                body_ids,
                num_envs=32,
                nbody=env.model.nbody,
                chance=1 / 6,
                mass_kg=(1.0, 10.0),
                speed_mps=5.0,
                step_s=1 / 30,
            )
            pushed = np.flatnonzero(np.abs(pushes).sum(-1).ravel())
            force = np.linalg.norm(pushes.reshape(-1, 6)[pushed, :3], axis=1)
            assert ((force >= 150 - 1e-9) & (force <= 1500 + 1e-9)).all()
            assert not pushes[..., 2:].any()  # horizontal forces, no torque
            per_agent = [np.abs(pushes[:, ids]).sum(axis=(1, 2)) > 0 for ids in body_ids]
            # At most one body of each agent per step.
            assert (np.count_nonzero(np.abs(pushes).sum(-1), axis=1) <= 2).all()
            hits.append(np.stack(per_agent, 1))
        share = np.mean(hits)
        assert 0.11 < share < 0.23, share
        tracker = Tracker(data, config, env.config, pushes=np.random.default_rng(0))
        tracker.reset(env, np.arange(32), np.random.default_rng(0))
        pushed = [tracker.step(env, np.zeros((32, 2, 28))).pushed for _ in range(10)]
        assert 0.08 < np.mean(pushed) < 0.26
        quiet = Tracker(data, config, env.config)  # no generator: no pushes
        quiet.reset(env, np.arange(32), np.random.default_rng(0))
        assert not quiet.step(env, np.zeros((32, 2, 28))).pushed.any()


def test_hard_starts_fall_in_the_second_before_where_episodes_failed(data):
    with _env(64) as env:
        config = TrackConfig(hard_start_share=1.0, hard_start_window_s=0.5)
        tracker = Tracker(data, config, env.config)
        library = tracker.libraries[1]
        punch = int(library.start[1])
        # No failure yet: uniform. Then agent 1 failed at the punch's frame 40 (twice) and
        # the walk's frame 5: its starts fall in the 15 frames up to each, two to one.
        np.testing.assert_allclose(tracker.start_weights(1), 1 / len(library.startable))
        tracker.failures[1][punch + 40] = 2.0
        tracker.failures[1][5] = 1.0
        tracker.reset(env, np.arange(64), np.random.default_rng(0))
        _, frame = tracker.clip_and_frame()
        clip = tracker.clip_and_frame()[0][:, 1]
        starts = tracker.flat[:, 1]
        in_punch = (starts >= punch + 25) & (starts <= punch + 40)
        in_walk = starts <= 5
        assert (in_punch | in_walk).all(), starts
        assert 30 < in_punch.sum() < 60 and in_walk.sum() > 5
        assert (clip[in_punch] == 1).all() and (frame[in_walk, 1] <= 5).all()
        # Agent 0 failed nowhere: its starts stay uniform over every frame.
        assert len(np.unique(tracker.flat[:, 0])) > 32
        weights = tracker.start_weights(1)
        assert weights.sum() == pytest.approx(1.0)
        # A failure at a clip's first frames does not reach into the clip before it.
        tracker.failures[1][:] = 0
        tracker.failures[1][punch + 1] = 1.0
        weights = tracker.start_weights(1)
        assert set(library.startable[weights > 0]) == {punch, punch + 1}
        # Mixed: half uniform.
        half = Tracker(data, dataclasses.replace(config, hard_start_share=0.5), env.config)
        half.failures[1][punch + 1] = 1.0
        assert half.start_weights(1).min() == pytest.approx(0.5 / len(library.startable))


def test_zero_corrections_play_the_clip_back_closely_for_a_few_steps(data):
    # PD targets on the next reference frame (a zero correction), from each clip's first frame,
    # 8 steps. Measured: body errors 2.6 (punch) and 6.6 cm (walk), roots 3.7-3.8 cm; holding
    # the first frame's pose instead (the correction that undoes the reference's motion) ends
    # twice as far from the walk (13.5 cm).
    with _env(2) as env:
        tracker = _tracker(data, env)
        starts = np.array([[0, 0], [1, 1]])
        errors = {}
        for mode in ("reference", "hold"):
            tracker.reset(env, np.arange(2), np.random.default_rng(0), clips=starts)
            first = tracker.actions(np.zeros((2, 2, 28)))
            for _ in range(8):
                zero = np.zeros((2, 2, 28))
                held = first - tracker.actions(zero)
                step = tracker.step(env, zero if mode == "reference" else held)
                assert not step.terminal.any()
            errors[mode] = (step.body_error[:, 0], step.root_error[:, 0])
    body, root = errors["reference"]
    assert body.max() < 0.08 and root.max() < 0.06, errors
    assert errors["hold"][0][0] > 1.5 * body[0]  # the walk


def test_an_agent_whose_root_drifts_from_its_reference_ends_terminally(data):
    limit = TrackConfig().root_limit_m
    with _env(2) as env:
        tracker = _tracker(data, env)
        tracker.reset(env, np.arange(2), np.random.default_rng(0), clips=np.array([[1, 1]] * 2))
        qpos = np.stack([[d.qpos[a.qpos] for a in env.index.agents] for d in env.datas])
        qvel = np.stack([[d.qvel[a.qvel] for a in env.index.agents] for d in env.datas])
        # Agent 0 of environment 0 is put beside its reference, further than the limit; that
        # of environment 1 within it.
        qpos[0, 0, 1] += limit + 0.1
        qpos[1, 0, 1] += limit - 0.2
        env.set_states(np.arange(2), qpos, qvel)
        step = tracker.step(env, np.zeros((2, 2, 28)))
    np.testing.assert_array_equal(step.terminal, [[True, False], [False, False]])
    np.testing.assert_array_equal(step.terminated, [True, False])
    assert not step.truncated.any() and not step.fell.any()
    assert step.root_error[0, 0] > limit > step.root_error[1, 0]


def test_an_anchored_tracker_moves_a_stray_reference_back_under_its_body(data):
    """`TrackConfig.anchor_m`, in training: the same drift as above moves agent 0's reference
    of environment 0 back under its pelvis (a root error of the step's own motion, no ending),
    and leaves environment 1's, within the anchor, where it was; a tracker not anchored (the
    gate's) ends the episode as above."""
    config = TrackConfig(anchor_m=0.3)
    with _env(2) as env:
        tracker = Tracker(data, config, env.config, anchored=True)
        tracker.reset(env, np.arange(2), np.random.default_rng(0), clips=np.array([[1, 1]] * 2))
        qpos = np.stack([[d.qpos[a.qpos] for a in env.index.agents] for d in env.datas])
        qvel = np.stack([[d.qvel[a.qvel] for a in env.index.agents] for d in env.datas])
        qpos[0, 0, 1] += config.root_limit_m + 0.1
        qpos[1, 0, 1] += config.anchor_m - 0.1
        env.set_states(np.arange(2), qpos, qvel)
        before = tracker.offset.copy()
        step = tracker.step(env, np.zeros((2, 2, 28)))
        assert not step.terminal.any() and not step.done.any()
        moved = tracker.offset - before
        assert moved[0, 0, 1] == pytest.approx(config.root_limit_m + 0.1, abs=0.05)
        assert moved[0, 0, 2] == 0.0 and not moved[0, 1].any() and not moved[1].any()
        assert step.root_error[0, 0] < 0.05
        assert step.root_error[1, 0] > config.anchor_m - 0.15
    with _env(2) as env:
        loose = Tracker(data, config, env.config)
        loose.reset(env, np.arange(2), np.random.default_rng(0), clips=np.array([[1, 1]] * 2))
        env.set_states(np.arange(2), qpos, qvel)
        assert loose.step(env, np.zeros((2, 2, 28))).terminal[0, 0]


# ---------------------------------------------------------------- training


@pytest.mark.parametrize("stepping", ["rollout", "warp"])
def test_a_tracking_run_resumes_from_its_checkpoint_exactly(data, stepping):
    # With hard starts and pushes, whose failure counts and generator are part of the state.
    config = dataclasses.replace(
        TINY,
        env=dataclasses.replace(TINY.env, stepping=stepping),
        track=TrackConfig(hard_start_share=0.5, push_every_s=0.5),
    )
    gates = []

    def failed(whole: Trainer) -> None:
        # Episodes failed, so the hard starts had failures to draw near.
        assert sum(f.sum() for f in whole.objective.tracker.failures) > 0

    def gated(resumed: Trainer) -> None:
        gates.append(track_gate(resumed.nets.policy, data, config))

    expected = resumes_exactly(config, data, whole_done=failed, resumed_done=gated)
    for name in ("reward_total", "reward_pose", "body_error_cm", "root_error_cm", "policy_loss"):
        assert np.isfinite(expected[0][name]), name
    assert 0 < expected[0]["reward_total"] <= 1
    assert "motion_accuracy_real" not in expected[0]  # no discriminators
    (gate,) = gates
    # The gate: both agents on both clips from the first frame, acting on the mean.
    assert [(r.agent, r.clip) for r in gate.rows] == [
        (0, "walk"),
        (0, "punch"),
        (1, "walk"),
        (1, "punch"),
    ]
    assert 0 <= gate.finished_pct <= 100 and gate.body_error_cm > 0
    assert all(1 <= r.frames <= 64 for r in gate.rows)


def test_a_policy_that_follows_a_short_clip_finishes_it_and_not_a_clip_it_loses(assets):
    # A zero correction (PD targets on the next reference frame), measured: the walk's first 17
    # frames followed to the end (6.7 cm body error), the whole punch lost after 21 of its 64
    # steps (its root drifts off).
    from models.maaip.objectives import tracking_networks

    full = {name: retarget(load_deepmimic(clip_path(assets, name))) for name in ("walk", "punch")}
    clips = {"walk": full["walk"][:17], "punch": full["punch"]}
    data = tracking_data((clips, clips), BONES, fps=30.0, key="clips:walk[:17],punch")
    policy, _ = tracking_networks(TINY, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        policy.net[-1].weight.zero_()
        policy.net[-1].bias.zero_()
    gate = track_gate(policy, data, TINY)
    # Finished: every one of the clip's 16 steps tracked; lost: ended before its last frame.
    assert [(r.agent, r.clip, r.finished, r.frames) for r in gate.rows] == [
        (0, "walk", True, 16),
        (0, "punch", False, 21),
        (1, "walk", True, 16),
        (1, "punch", False, 21),
    ]
    assert gate.finished_pct == 50.0
    assert gate.rows[0].body_error_cm < 8.0


def test_the_gate_is_met_on_all_three_figures_and_held_on_three_of_the_last_five_checks():
    track = TrackConfig()
    # 13 of 14 clips (92.9 %) at 5 cm and 10 cm meets it; each figure alone can miss it.
    assert gate_met(Gate(100 * 13 / 14, 5.0, 10.0, ()), track)
    assert not gate_met(Gate(100 * 12 / 14, 3.0, 5.0, ()), track)
    assert not gate_met(Gate(100.0, 5.01, 5.0, ()), track)
    assert not gate_met(Gate(100.0, 3.0, 10.01, ()), track)
    # Touched once, or twice long ago, is not held; 3 of the last 5 is, in any order.
    assert not gate_held([True], track)
    assert not gate_held([True, True, False, False, False, False], track)
    assert gate_held([False, True, False, True, True], track)
    assert gate_held([True, False, True, False, False, True, True, False, True], track)
    assert not gate_held([True, True, True, False, False, False, True, True], track)
    assert gate_held([True], dataclasses.replace(track, gate_window=1, gate_needed=1))
    with pytest.raises(ValueError, match="gate_needed"):
        TrackConfig(gate_window=2, gate_needed=3)


def test_a_trackers_value_reads_its_own_agent_only_unless_told():
    from models.maaip.objectives import tracking_networks

    generator = torch.Generator().manual_seed(0)
    _, own = tracking_networks(TINY, generator=generator)
    both_config = dataclasses.replace(TINY, track=TrackConfig(value_sees_partner=True))
    _, both = tracking_networks(both_config, generator=generator)
    assert own.net[0].in_features == TRACK_OBSERVATION_DIM + 2
    assert both.net[0].in_features == 2 * TRACK_OBSERVATION_DIM + 2
    obs = torch.randn(6, TRACK_OBSERVATION_DIM, generator=generator)
    other = torch.randn(6, TRACK_OBSERVATION_DIM, generator=generator)
    agent = torch.tensor([0, 1, 0, 1, 0, 1])
    with torch.no_grad():
        assert torch.equal(own(obs, other, agent), own(obs, other.flip(0), agent))
        assert not torch.equal(both(obs, other, agent), both(obs, other.flip(0), agent))


def test_each_objective_takes_its_own_data(data, assets):
    with pytest.raises(ValueError, match="'track' trains on TrackingData"):
        Trainer(TINY, clip_demonstrations(assets, "punch"))
    with pytest.raises(ValueError, match="'maaip' trains on Demonstrations"):
        Trainer(dataclasses.replace(TINY, objective="maaip"), data)
    with pytest.raises(ValueError, match="at 30.0 fps, the policy steps at 60 Hz"):
        Trainer(dataclasses.replace(TINY, env=EnvConfig(policy_hz=60, num_envs=4)), data)
    with pytest.raises(ValueError, match="control_task must be 'none'"):
        TrainConfig(objective="track", reward=RewardConfig(w_control=0.5, control_task="heading"))
    with pytest.raises(ValueError, match="train.objective must be one of"):
        TrainConfig(objective="imitate")
