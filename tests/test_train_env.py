"""The two-fighter arena (models.arena.mjcf) and the batched training environment
(models.arena.env): placement, observations, falls, damage, batched stepping, bad inputs."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from array_api_compat import is_torch_array

from models.arena.config import EnvConfig
from models.arena.env import ArenaEnv, to_host
from models.arena.mjcf import DAMAGE_BODIES, arena_index, arena_mjcf
from models.arena.puppet import Puppet
from models.arena.starts import ReferenceMotions, centred_pair, geom_bottoms
from models.humanoid.boxer import BoneLengths
from models.humanoid.compiled import body_state, humanoid_index
from models.humanoid.kinematics import (
    HINGE_NAMES,
    action_to_joint_targets,
    heading_frame,
    joint_targets_to_action,
)
from models.humanoid.observations import SELF_DIM, observation, self_observation

SMALL = BoneLengths().scaled(0.9)


def _env(**config) -> ArenaEnv:
    """An environment that starts every episode at a reference frame with its velocities unless
    told: these tests check what the reference's motion does."""
    config = {
        "num_envs": 2,
        "threads": 1,
        "reset_velocity": "reference",
        "standing_share": 0.0,
        **config,
    }
    return ArenaEnv(EnvConfig(**config), np.random.default_rng(0))


def _standing(env: ArenaEnv) -> ReferenceMotions:
    """One frame: both fighters at rest, as the arena's qpos0 puts them."""
    q = env.model.qpos0
    zero = np.zeros((1, 34))
    return ReferenceMotions(q[None, :35], zero, q[None, 35:], zero)


def _floor_distances(model: mujoco.MjModel, data: mujoco.MjData, geoms) -> np.ndarray:
    """Signed distance of each geom to the floor by MuJoCo's own narrow phase."""
    floor = model.geom("floor").id
    return np.array([mujoco.mj_geomDistance(model, data, floor, g, 10.0, None) for g in geoms])


# ---------------------------------------------------------------- arena


def test_arena_holds_two_boxers_that_touch_each_other_and_the_floor_only():
    model = mujoco.MjModel.from_xml_string(arena_mjcf((BoneLengths(), SMALL), timestep=1 / 120))
    assert (model.nq, model.nv, model.nu) == (70, 68, 56)
    assert model.opt.timestep == pytest.approx(1 / 120)
    red, blue = humanoid_index(model, prefix="a0/"), humanoid_index(model, prefix="a1/")
    assert (red.qpos, blue.qpos) == (slice(0, 35), slice(35, 70))
    index = arena_index(model)
    owner = index.agent_of_geom
    floor = model.geom("floor").id
    for g1 in range(model.ngeom):
        for g2 in range(g1 + 1, model.ngeom):
            collide = bool(
                model.geom_contype[g1] & model.geom_conaffinity[g2]
                or model.geom_contype[g2] & model.geom_conaffinity[g1]
            )
            if floor in (g1, g2):
                assert collide  # the floor touches every geom of both fighters
            else:
                assert collide == (owner[g1] != owner[g2]), (
                    model.geom(g1).name,
                    model.geom(g2).name,
                )
    for a, prefix in enumerate(("a0/", "a1/")):
        bodies = {model.body(model.geom_bodyid[g]).name for g in index.damage_geoms[a]}
        assert bodies == {prefix + b for b in DAMAGE_BODIES}
        names = [model.geom(g).name for g in index.striker_geoms[a]]
        assert names == [prefix + "right_glove", prefix + "left_glove"]
        assert model.geom(index.head_geoms[a]).name == prefix + "head"
        assert list(index.actuators[a]) == list(range(28 * a, 28 * (a + 1)))
    # At qpos0 they stand 1.2 m apart across the origin, facing each other, soles on the floor.
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    assert data.qpos[[0, 35]] == pytest.approx([-0.6, 0.6])
    facing = heading_frame(np.stack([data.qpos[3:7], data.qpos[38:42]]))[:, :, 0]
    assert facing == pytest.approx(np.array([[1.0, 0, 0], [-1.0, 0, 0]]), abs=1e-12)
    fighters = np.flatnonzero(owner >= 0)
    assert _floor_distances(model, data, fighters).min() == pytest.approx(0.0, abs=1e-9)
    assert geom_bottoms(model, data, fighters) == pytest.approx(
        _floor_distances(model, data, fighters), abs=1e-9
    )


def test_arena_sensors_and_bad_arguments():
    plain = mujoco.MjModel.from_xml_string(arena_mjcf())
    assert plain.nsensor == 0 and arena_index(plain).sensors is None
    sensed = mujoco.MjModel.from_xml_string(arena_mjcf(contact_sensors=True))
    layout = arena_index(sensed).sensors
    assert layout is not None and layout.damage.shape == (2, 3)
    with pytest.raises(ValueError, match="prefixes"):
        arena_mjcf(prefixes=("a/", "a/"))
    with pytest.raises(ValueError, match="timestep"):
        arena_mjcf(timestep=-1.0)
    with pytest.raises(ValueError, match="bones"):
        arena_mjcf((BoneLengths(),))


# ---------------------------------------------------------------- reset


def test_reset_places_both_fighters_at_the_reference_frame(punch):
    frames = np.array([0, 12, 30, 50])
    with _env(num_envs=4) as env:
        obs = env.reset(np.arange(4), punch, frames=frames)
        assert obs.shape == (4, 2, 274)
        agents = env.index.agents
        fighters = np.flatnonzero(env.index.agent_of_geom >= 0)
        for k, frame in enumerate(frames):
            data = env.datas[k]
            q0, q1 = data.qpos[agents[0].qpos], data.qpos[agents[1].qpos]
            shift = q0[:2] - punch.qpos0[frame, :2]
            # One horizontal shift for both, centring the pelvises on the origin; all else equal.
            assert q1[:2] - punch.qpos1[frame, :2] == pytest.approx(shift, abs=1e-12)
            assert (q0[:2] + q1[:2]) / 2 == pytest.approx([0.0, 0.0], abs=1e-12)
            assert np.array_equal(q0[3:], punch.qpos0[frame, 3:])
            assert np.array_equal(q1[3:], punch.qpos1[frame, 3:])
            assert np.array_equal(data.qvel[agents[0].qvel], punch.qvel0[frame])
            assert np.array_equal(data.qvel[agents[1].qvel], punch.qvel1[frame])
            # Heights change only to put each fighter's lowest point on the floor.
            for agent in range(2):
                mine = np.flatnonzero(env.index.agent_of_geom == agent)
                gap = _floor_distances(env.model, data, mine).min()
                assert gap == pytest.approx(0.0, abs=1e-9)
            assert _floor_distances(env.model, data, fighters).min() >= -1e-9


def test_reset_grounds_a_sunk_or_floating_fighter_and_draws_frames_from_the_rng(punch):
    for offset in (-0.2, 0.3):  # sunk into the floor, then floating as lifted footage can be
        moved = ReferenceMotions(
            punch.qpos0 + np.eye(35)[2] * offset, punch.qvel0, punch.qpos1, punch.qvel1
        )
        with _env(num_envs=3) as env:
            env.reset([0, 1, 2], moved, frames=[5, 6, 7])
            mine = np.flatnonzero(env.index.agent_of_geom == 0)
            for data in env.datas:
                gap = _floor_distances(env.model, data, mine).min()
                assert gap == pytest.approx(0.0, abs=1e-9)
    draws = []
    for _ in range(2):
        with _env(num_envs=8) as env:
            env.reset(np.ones(8, dtype=bool), punch)
            draws.append(np.array([d.qpos[3:7].copy() for d in env.datas]))
    assert np.array_equal(draws[0], draws[1])  # one seed, one draw
    assert len({tuple(q) for q in draws[0]}) > 1  # frames differ between environments


def test_reset_velocities_are_zeroed_clipped_or_kept(punch):
    fast = ReferenceMotions(punch.qpos0, punch.qvel0 * 10, punch.qpos1, punch.qvel1 * 10)
    frames = [3, 20]
    got = {}
    for mode in ("zero", "clip", "reference"):
        with _env(reset_velocity=mode, reset_speed_limit=2.0) as env:
            env.reset([0, 1], fast, frames=frames)
            got[mode] = np.array([d.qvel[env.index.agents[0].qvel] for d in env.datas])
    assert not got["zero"].any()
    assert np.array_equal(got["reference"], fast.qvel0[frames])
    assert np.array_equal(got["clip"], np.clip(fast.qvel0[frames], -2.0, 2.0))
    assert np.abs(fast.qvel0[frames]).max() > 2.0  # the clip did clip
    with pytest.raises(ValueError, match="reset_velocity"):
        EnvConfig(reset_velocity="half")


def test_a_share_of_resets_starts_standing_where_the_frame_stands(punch):
    with _env(num_envs=64, standing_share=0.5) as env:
        env.reset(np.arange(64), punch)
        agents = env.index.agents
        hinges = np.array([d.qpos[agents[0].qpos][7:] for d in env.datas])
        standing = ~hinges.any(axis=1)
        assert 16 < standing.sum() < 48
        for data in np.array(env.datas)[standing]:
            for agent in agents:
                q = data.qpos[agent.qpos]
                assert not q[7:].any() and not data.qvel[agent.qvel].any()
                assert np.linalg.norm(q[4:6]) == pytest.approx(0.0, abs=1e-12)  # yaw only
            mine = np.flatnonzero(env.index.agent_of_geom == 0)
            assert _floor_distances(env.model, data, mine).min() == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(ValueError, match="standing_share"):
        EnvConfig(standing_share=1.5)


def test_standing_starts_take_the_reference_stance(punch):
    stance = np.stack([np.linspace(-0.2, 0.2, 28), np.linspace(0.1, -0.1, 28)])
    with_stance = ReferenceMotions(
        punch.qpos0, punch.qvel0, punch.qpos1, punch.qvel1, stance=stance
    )
    with _env(num_envs=8, standing_share=1.0) as env:
        env.reset(np.arange(8), with_stance)
        for data in env.datas:
            for agent, hinges in zip(env.index.agents, stance, strict=True):
                assert data.qpos[agent.qpos][7:] == pytest.approx(hinges)
                assert not data.qvel[agent.qvel].any()
    with pytest.raises(ValueError, match="stance"):
        ReferenceMotions(punch.qpos0, punch.qvel0, punch.qpos1, punch.qvel1, stance=stance[:1])


def test_centred_pair_and_facing_reference_geometry(punch):
    a, b = centred_pair(punch.qpos0[:3], punch.qpos1[:3])
    assert a[:, :2] + b[:, :2] == pytest.approx(np.zeros((3, 2)), abs=1e-12)
    # Agent 1 starts 1.2 m in front of agent 0 and faces it.
    facing0 = heading_frame(punch.qpos0[0, 3:7])[:, 0]
    facing1 = heading_frame(punch.qpos1[0, 3:7])[:, 0]
    gap = punch.qpos1[0, :3] - punch.qpos0[0, :3]
    assert gap == pytest.approx(1.2 * facing0, abs=1e-9)
    assert facing1 == pytest.approx(-facing0, abs=1e-9)


# ---------------------------------------------------------------- observations


@pytest.mark.parametrize("stepping", ["rollout", "threads", "warp"])
def test_observations_are_the_dataset_functions_on_the_simulated_state(punch, stepping):
    # Warp observes on its device in float32 (measured: 1.3e-6 at most).
    tol = 1e-5 if stepping == "warp" else 1e-10
    rng = np.random.default_rng(4)
    with _env(num_envs=3, stepping=stepping) as env:
        env.reset([0, 1, 2], punch, frames=[3, 20, 40])
        for _ in range(3):
            result = env.step(rng.normal(0.0, 0.3, (3, 2, 28)))
        # Warp's stay on its device, where the trainer takes them from.
        assert is_torch_array(result.observation) == (stepping == "warp")
        observed, own = to_host(result.observation), to_host(result.self_observation)
        agents = env.index.agents
        for k, data in enumerate(env.datas):
            fresh = mujoco.MjData(env.model)
            fresh.qpos[:], fresh.qvel[:] = data.qpos, data.qvel
            mujoco.mj_forward(env.model, fresh)
            me = body_state(env.model, fresh, agents[0])
            them = body_state(env.model, fresh, agents[1])
            assert observed[k, 0] == pytest.approx(observation(me, them), abs=tol)
            assert observed[k, 1] == pytest.approx(observation(them, me), abs=tol)
            assert own[k, 1] == pytest.approx(self_observation(them), abs=tol)
        assert env.observe() == pytest.approx(observed, abs=tol)
        # A step that does not observe the opponent (a tracker's) gives o^self alone.
        alone = env.step(rng.normal(0.0, 0.3, (3, 2, 28)), opponent=False)
        assert to_host(alone.observation).shape == (3, 2, SELF_DIM)
        assert to_host(alone.observation) == pytest.approx(env.observe()[..., :SELF_DIM], abs=tol)


# ---------------------------------------------------------------- falls and time-outs


@pytest.mark.parametrize("stepping", ["rollout", "threads", "warp"])
def test_zero_actions_stand_and_a_shove_knocks_a_fighter_down(stepping):
    with _env(num_envs=2, stepping=stepping) as env:
        reference = _standing(env)
        env.reset([0, 1], reference)
        for _ in range(30):  # one second at the rest targets
            result = env.step(np.zeros((2, 2, 28)))
            assert not result.done.any()
        for data in env.datas:  # Warp leaves the MjData their state, not its kinematics
            mujoco.mj_kinematics(env.model, data)
        heads = np.array([d.geom_xpos[env.index.head_geoms, 2] for d in env.datas])
        assert heads.min() > 1.6

        shoved = ReferenceMotions(
            reference.qpos0, reference.qvel0, reference.qpos1, reference.qvel1 + np.eye(34)[1] * 2.5
        )
        env.reset([0], reference)
        env.reset([1], shoved)  # agent 1 of env 1 starts sliding sideways at 2.5 m/s
        for _ in range(60):
            result = env.step(np.zeros((2, 2, 28)))
            if result.done[1]:
                break
        assert result.terminated[1] and not result.truncated[1]
        assert result.fell[1].tolist() == [False, True]
        assert not result.done[0]


def _momentum(env: ArenaEnv, data: mujoco.MjData, agent: int) -> np.ndarray:
    """(3,) the linear momentum of agent ``agent``'s whole body (its pelvis's subtree)."""
    mujoco.mj_forward(env.model, data)
    mujoco.mj_subtreeVel(env.model, data)
    root = env.index.agents[agent].body_ids[0]
    return env.model.body_subtreemass[root] * data.subtree_linvel[root]


@pytest.mark.parametrize("stepping", ["rollout", "threads", "warp"])
def test_a_push_gives_its_impulse_in_its_step_and_is_gone_after(stepping):
    """In the air (no contact, so gravity is the only other force, the same in both worlds), a
    push of 900 N for a policy step on agent 0's pelvis in world 0 leaves that fighter with
    30 N s more momentum than its twin in world 1 (to 1 %: the joints' armature is inertia the
    bodies' momentum leaves out), the other fighter unmoved; the next step, unpushed, adds
    nothing."""
    with _env(num_envs=2, stepping=stepping) as env:
        q = np.tile(env.model.qpos0, (2, 1)).reshape(2, 2, 35)
        q[:, :, 2] += 2.0
        env.set_states([0, 1], q, np.zeros((2, 2, 34)))
        pushes = np.zeros((2, env.model.nbody, 6))
        pelvis = env.index.agents[0].body_ids[0]
        pushes[0, pelvis, :3] = [900.0, -300.0, 0.0]
        env.step(np.zeros((2, 2, 28)), pushes=pushes)
        impulse = pushes[0, pelvis, :3] / env.config.policy_hz  # (30, -10, 0) N s
        tolerance = 1e-3 if stepping == "warp" else 1e-8  # Warp steps in float32
        for after in range(2):
            datas = env.datas
            gained = _momentum(env, datas[0], 0) - _momentum(env, datas[1], 0)
            np.testing.assert_allclose(gained, impulse, atol=0.01 * np.linalg.norm(impulse))
            other = _momentum(env, datas[0], 1) - _momentum(env, datas[1], 1)
            np.testing.assert_allclose(other, 0.0, atol=tolerance)
            assert not any(d.xfrc_applied.any() for d in datas)
            if after == 0:
                env.step(np.zeros((2, 2, 28)))
        with pytest.raises(ValueError, match="pushes must be finite"):
            env.step(np.zeros((2, 2, 28)), pushes=np.zeros((2, 3, 6)))


@pytest.mark.parametrize("stepping", ["rollout", "threads", "warp"])
def test_a_blown_up_simulation_ends_its_episode_with_finite_numbers(punch, stepping):
    with _env(num_envs=2, stepping=stepping) as env:
        env.reset([0, 1], punch, frames=[5, 5])
        env.datas[1].qvel[:] = 1e12  # far beyond what MuJoCo integrates (mjMAXVAL is 1e10)
        result = env.step(np.zeros((2, 2, 28)))
        assert result.unstable.tolist() == [False, True]
        assert result.terminated.tolist() == [False, True]
        assert result.fell[1].tolist() == [False, False]  # not counted as a fall
        observed = to_host(result.observation)
        assert np.isfinite(observed).all() and np.isfinite(to_host(result.damage)).all()
        assert not observed[1].any() and observed[0].any()
        # MuJoCo did not quietly restart it at the rest pose: the state is left for the reset.
        assert not np.isfinite(env.datas[1].qpos).all() or np.abs(env.datas[1].qvel).max() > 1e10
        env.reset([1], punch, frames=[5])
        result = env.step(np.zeros((2, 2, 28)))
        assert not result.unstable.any()


def test_time_limit_truncates_without_terminating():
    with _env(episode_s=0.2) as env:
        env.reset([0, 1], _standing(env))
        for step in range(6):
            result = env.step(np.zeros((2, 2, 28)))
            assert result.done.tolist() == [step == 5] * 2
        assert result.truncated.all() and not result.terminated.any()
        env.reset([0], _standing(env))
        assert env.elapsed.tolist() == [0, 6]


# ---------------------------------------------------------------- damage


def _jab_setup(env: ArenaEnv) -> tuple[ReferenceMotions, np.ndarray]:
    """Agent 0 lunges at 1.5 m/s with its right arm raised forward, its glove 2 cm short of
    agent 1's head; actions hold agent 0's arm and agent 1's rest pose."""
    q0, q1 = env.model.qpos0[:35].copy(), env.model.qpos0[35:].copy()
    q0[:2] = 0.0
    q0[7 + HINGE_NAMES.index("right_shoulder_y")] = -1.9  # arm forward, 19 deg above level
    q1[:2] = (0.833, -0.185)  # head in line with agent 0's right arm
    v0 = np.zeros(34)
    v0[0] = 1.5
    reference = ReferenceMotions(q0[None], v0[None], q1[None], np.zeros((1, 34)))
    actions = np.zeros((env.num_envs, 2, 28))
    actions[:, 0] = joint_targets_to_action(q0[7:])
    return reference, actions


def _slow_damage(model: mujoco.MjModel, data: mujoco.MjData, prefixes=("a0/", "a1/")):
    """Every contact's normal force on a head/torso/pelvis geom from the other fighter."""
    damage = np.zeros(2)
    force = np.zeros(6)
    for c in range(data.ncon):
        names = [model.geom(g).name for g in data.contact.geom[c]]
        bodies = [model.body(model.geom_bodyid[g]).name for g in data.contact.geom[c]]
        for side in (0, 1):
            other = names[1 - side]
            for a, prefix in enumerate(prefixes):
                target = bodies[side] in {prefix + b for b in DAMAGE_BODIES}
                if target and other.startswith(prefixes[1 - a]):
                    mujoco.mj_contactForce(model, data, c, force)
                    damage[a] += force[0]
    return damage


def test_a_glove_on_the_head_damages_the_one_hit_and_matches_a_slow_count():
    with _env(num_envs=1, stepping="threads") as env:
        reference, actions = _jab_setup(env)
        env.reset([0], reference)
        # Replay the same physics in a second MjData, counting contacts the slow way.
        replay = mujoco.MjData(env.model)
        replay.qpos[:], replay.qvel[:] = env.datas[0].qpos, env.datas[0].qvel
        targets = action_to_joint_targets(actions[0])
        replay.ctrl[:] = np.clip(targets.reshape(-1), *env.model.actuator_ctrlrange.T)
        total = np.zeros(2)
        hits = set()
        for _ in range(8):
            result = env.step(actions)
            slow = np.zeros(2)
            for _ in range(env.config.substeps):
                mujoco.mj_step(env.model, replay)
                slow += _slow_damage(env.model, replay)
                for c in range(replay.ncon):
                    hits.add(tuple(sorted(env.model.geom(g).name for g in replay.contact.geom[c])))
            assert np.array_equal(result.damage[0], slow)
            total += result.damage[0]
        assert ("a0/right_glove", "a1/head") in hits
        assert total[0] == 0.0 and total[1] > 500.0  # newtons, summed over the steps
        assert not result.done.any()

    # mujoco.rollout reads the same contacts through sensors: the same damage.
    with _env(num_envs=1, stepping="rollout") as env:
        env.reset([0], reference)
        rollout_total = sum(env.step(actions).damage[0] for _ in range(8))
    assert rollout_total == pytest.approx(total, rel=1e-6)


# ---------------------------------------------------------------- batched stepping


def test_threaded_stepping_is_bitwise_sequential_stepping(punch):
    frames = [0, 9, 18, 27, 36, 45]
    rng = np.random.default_rng(7)
    actions = rng.normal(0.0, 0.4, (6, 6, 2, 28))
    with _env(num_envs=6, threads=2, stepping="threads") as env:
        env.reset(np.arange(6), punch, frames=frames)
        start = [(d.qpos.copy(), d.qvel.copy()) for d in env.datas]
        results = [env.step(a) for a in actions]
        threaded = [(d.qpos.copy(), d.qvel.copy()) for d in env.datas]
        model, ctrlrange = env.model, env.model.actuator_ctrlrange
        substeps = env.config.substeps
    # The obviously correct way: one MjData at a time, mj_step after mj_step.
    for k, (qpos, qvel) in enumerate(start):
        data = mujoco.MjData(model)
        data.qpos[:], data.qvel[:] = qpos, qvel
        for a in actions:
            data.ctrl[:] = np.clip(action_to_joint_targets(a[k]).reshape(-1), *ctrlrange.T)
            for _ in range(substeps):
                mujoco.mj_step(model, data)
        assert np.array_equal(data.qpos, threaded[k][0])
        assert np.array_equal(data.qvel, threaded[k][1])
    with _env(num_envs=6, threads=1, stepping="threads") as env:
        env.reset(np.arange(6), punch, frames=frames)
        sequential = [env.step(a) for a in actions]
    for one, two in zip(results, sequential, strict=True):
        assert np.array_equal(one.observation, two.observation)
        assert np.array_equal(one.damage, two.damage)
        assert np.array_equal(one.fell, two.fell)
    # mujoco.rollout: the same physics up to the solver's warm start, and the same on 1 or 2
    # threads.
    rolled = []
    for threads in (1, 2):
        with _env(num_envs=6, threads=threads, stepping="rollout") as env:
            env.reset(np.arange(6), punch, frames=frames)
            rolled.append([env.step(a) for a in actions])
            for k, data in enumerate(env.datas):
                assert data.qpos == pytest.approx(threaded[k][0], abs=1e-8)
    assert rolled[0][-1].observation == pytest.approx(results[-1].observation, abs=1e-6)
    for one, two in zip(*rolled, strict=True):
        assert np.array_equal(one.observation, two.observation)
        assert np.array_equal(one.damage, two.damage)


@pytest.mark.parametrize("stepping", ["rollout", "threads", "warp"])
def test_physics_rates_follow_the_config(stepping):
    for substeps, timestep in ((2, 1 / 60), (4, 1 / 120)):
        with _env(substeps=substeps, stepping=stepping) as env:
            assert env.model.opt.timestep == pytest.approx(timestep)
            before = env.datas[0].time
            env.step_physics()
            assert env.datas[0].time - before == pytest.approx(1 / 30)
            assert env.elapsed.tolist() == [0, 0]


# ---------------------------------------------------------------- bad inputs


def test_bad_inputs_raise_clear_errors(punch):
    with _env() as env:
        env.reset([0, 1], punch)
        with pytest.raises(ValueError, match=r"actions must have shape \(2, 2, 28\)"):
            env.step(np.zeros((2, 28)))
        bad = np.zeros((2, 2, 28))
        bad[1, 0, 5] = math.nan
        with pytest.raises(ValueError, match="actions must be finite; env 1, agent 0, action 5"):
            env.step(bad)
        with pytest.raises(ValueError, match="env_ids"):
            env.reset([2], punch)
        with pytest.raises(ValueError, match="frames"):
            env.reset([0], punch, frames=[punch.num_frames])
        with pytest.raises(ValueError, match="reference must be a ReferenceMotions"):
            env.reset([0], punch.qpos0)
        with pytest.raises(ValueError, match="ctrl"):
            env.step_physics(np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"qpos0 must have shape \(M, 35\)"):
        ReferenceMotions(punch.qpos0[:, :34], punch.qvel0, punch.qpos1, punch.qvel1)
    with pytest.raises(ValueError, match="qvel1 has 3 frames"):
        ReferenceMotions(punch.qpos0, punch.qvel0, punch.qpos1, punch.qvel1[:3])
    with pytest.raises(ValueError, match="qpos1 must be finite"):
        ReferenceMotions(punch.qpos0, punch.qvel0, punch.qpos1 * math.nan, punch.qvel1)
    with pytest.raises(ValueError, match="substeps"):
        EnvConfig(substeps=0)
    with pytest.raises(ValueError, match="stepping"):
        EnvConfig(stepping="gpu")


def test_a_puppet_follows_its_poses_and_pushes_the_other_fighter(punch):
    """A puppet agent (live sparring's partner) is exactly at each pose after a step, moving to
    it at constant velocity; its contacts move the other fighter; `place` puts an agent at rest
    on the floor and leaves the other alone."""
    env = _env(num_envs=1, stepping="threads")
    env.reset([0], punch, frames=[0])
    agents = env.index.agents
    start = env.datas[0].qpos[agents[1].qpos].copy()
    other = env.datas[0].qpos[agents[0].qpos].copy()
    pose = start.copy()
    pose[0] -= 0.02  # 2 cm towards the other fighter: 0.6 m/s
    pose[7 + HINGE_NAMES.index("right_knee")] = 0.3
    actions = np.zeros((1, 2, len(HINGE_NAMES)))
    result = env.step(actions, Puppet(1, pose[None]))
    data = env.datas[0]
    assert np.allclose(data.qpos[agents[1].qpos], pose, atol=1e-12)
    assert data.qvel[agents[1].qvel][0] == pytest.approx(-0.6, abs=1e-9)
    assert np.isfinite(result.observation).all()
    # Walked through where the other fighter stands, the puppet shoves it back.
    for _ in range(40):
        pose[0] -= 0.03
        env.step(actions, Puppet(1, pose[None]))
    assert env.datas[0].qpos[agents[0].qpos][0] < other[0] - 0.1
    # Placed: at rest, its lowest point on the floor, the other fighter where it was.
    before = env.datas[0].qpos[agents[1].qpos].copy()
    floating = other.copy()
    floating[2] += 0.5
    env.place(0, 0, floating)
    data = env.datas[0]
    mine = np.flatnonzero(env.index.agent_of_geom == 0)
    assert geom_bottoms(env.model, data, mine).min() == pytest.approx(0.0, abs=1e-9)
    assert not data.qvel[agents[0].qvel].any()
    assert np.array_equal(data.qpos[agents[1].qpos], before)
    with pytest.raises(ValueError, match="puppet.qpos must be finite"):
        env.step(actions, Puppet(1, np.full((1, 35), np.nan)))
    rollout = _env(num_envs=1)
    rollout.reset([0], punch, frames=[0])
    with pytest.raises(ValueError, match='a puppet needs EnvConfig.stepping "threads"'):
        rollout.step(actions, Puppet(1, pose[None]))
    env.close()
    rollout.close()


def test_a_puppet_by_the_root_moves_its_pelvis_and_leaves_its_limbs_to_its_actions(punch):
    env = _env(num_envs=1, stepping="threads")
    env.reset([0], punch, frames=[0])
    partner = env.index.agents[1]
    pose = env.datas[0].qpos[partner.qpos].copy()
    bent = pose.copy()
    bent[7:] += 0.5  # hinges a puppet by the root must not take
    actions = np.zeros((1, 2, len(HINGE_NAMES)))
    for _ in range(10):
        pose[1] += 0.01
        bent[1] = pose[1]
        env.step(actions, Puppet(1, bent[None], root_only=True))
    now = env.datas[0].qpos[partner.qpos]
    assert np.allclose(now[:7], bent[:7], atol=1e-12)
    assert np.abs(now[7:] - bent[7:]).mean() > 0.3  # nowhere near the bent hinges
    env.close()
