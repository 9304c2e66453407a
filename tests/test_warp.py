"""MuJoCo Warp stepping (`EnvConfig.stepping = "warp"`, on the CPU here) against MuJoCo's: the
same start states and actions give the same trajectories, falls and damage within measured
tolerances. Training on it resumes exactly: tests/test_train_loop.py and tests/test_tracker.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from models.arena.config import EnvConfig
from models.arena.env import ArenaEnv, to_host
from models.arena.starts import ReferenceMotions, geom_bottoms
from models.arena.stepping.warp import WarpPhysics

# Feet pressed this far into the floor at the start. The arena's resets put the soles exactly on
# it (distance 0), where MuJoCo (float64) leaves a foot's contact out of the first substep and
# Warp (float32, distance -9e-8) takes it in: that alone moved the roots 1 cm in the first
# policy step and 35 cm after 30 (measured with these actions), as any two ways of deciding a
# touching contact would. Pressed in, both take every contact from the start.
PRESSED_M = 0.002


def _play(stepping: str, actions: np.ndarray):
    """Both fighters of each of N arenas standing still at the arena's rest pose, pressed in,
    then `actions` (T, N, 2, 28); the qpos, falls and damage after each step."""
    n = actions.shape[1]
    config = EnvConfig(num_envs=n, threads=1, stepping=stepping)
    with ArenaEnv(config, np.random.default_rng(0)) as env:
        q = env.model.qpos0.copy()
        q[[2, 37]] -= PRESSED_M
        qvel = np.zeros((n, 2, 34))
        qvel[-1, 1, 1] = 2.5  # the last pair's agent 1 starts sliding sideways: it falls
        env.set_states(np.arange(n), np.tile([q[:35], q[35:]], (n, 1, 1)), qvel)
        qpos, fell, damage = [], [], []
        for a in actions:
            result = env.step(a)
            qpos.append(np.stack([d.qpos.copy() for d in env.datas]))
            fell.append(result.fell)
            damage.append(to_host(result.damage))
    return np.array(qpos), np.array(fell), np.array(damage)


def test_warp_follows_mujoco_for_30_policy_steps():
    # Six standing pairs, each with its own actions; in the last, agent 1 starts sliding and
    # falls half a second in.
    rng = np.random.default_rng(7)
    actions = rng.normal(0.0, 0.1, (30, 6, 2, 28))
    actions[:, 5] *= 3.0
    want_q, want_fell, _ = _play("threads", actions)
    got_q, got_fell, _ = _play("warp", actions)
    roots = np.r_[0:3, 35:38]
    # Measured: 0.026 mm for the roots and 6.5e-5 (m or rad) for any coordinate after 30 steps;
    # Warp's gravity 1e-5 too strong moves them 0.17 mm and 4.3e-4.
    assert np.abs(got_q[..., roots] - want_q[..., roots]).max() < 0.04e-3
    assert np.abs(got_q - want_q).max() < 1e-4
    assert want_fell[:, 5, 1].any() and not want_fell[:, :5].any()
    assert np.array_equal(got_fell, want_fell)


def test_a_jab_does_the_same_damage_within_3_5_percent():
    # Agent 0 lunges, glove first, at agent 1's head (tests/test_train_env.py's jab, started as
    # there: with the lunge's velocity, never standing).
    from test_train_env import _env, _jab_setup

    totals = {}
    for stepping in ("threads", "warp"):
        with _env(num_envs=1, stepping=stepping) as env:
            reference, actions = _jab_setup(env)
            env.reset([0], reference)
            totals[stepping] = sum(to_host(env.step(actions).damage)[0] for _ in range(8))
    # Measured: 3,751 N against 3,876, 3.24 % less (the soles start touching the floor, as above).
    assert totals["threads"][0] == totals["warp"][0] == 0.0
    assert totals["threads"][1] > 1000.0  # the jab lands
    assert totals["warp"][1] == pytest.approx(totals["threads"][1], rel=0.035)


def test_resets_on_the_device_start_where_mujocos_do(punch):
    # Episode starts from DeepMimic's punch, half of them standing in the rest pose, drawn by the
    # same generator; then two of the four arenas restart mid-episode, the others moving on. On
    # Warp the starts are grounded and observed on the device.
    import mujoco
    from test_train_env import _env

    reference = punch
    actions = np.random.default_rng(3).normal(0.0, 0.2, (4, 2, 28))
    got = {}
    for stepping in ("threads", "warp"):
        with _env(num_envs=4, stepping=stepping, standing_share=0.5) as env:
            first = to_host(env.reset(np.arange(4), reference))
            env.step(actions)
            again = to_host(env.reset([1, 3], reference))
            qpos = np.stack([d.qpos.copy() for d in env.datas])
            lowest = []
            for data in env.datas:
                mujoco.mj_kinematics(env.model, data)
                lowest.append(
                    [
                        geom_bottoms(
                            env.model, data, np.flatnonzero(env.index.agent_of_geom == a)
                        ).min()
                        for a in range(2)
                    ]
                )
            heading = to_host(env.heading_inputs(np.full((4, 2), 0.5)))
            got[stepping] = first, again, qpos, np.array(lowest), to_host(env.observe()), heading
            assert env.elapsed.tolist() == [1, 0, 1, 0]
    (first, again, qpos, lowest, observed, heading), want = got["warp"], got["threads"]
    # Warp's float32 poses and kinematics, measured: observations 2.4e-6 apart at most, poses
    # 9e-8 m, the lowest points 5e-8 m from the floor, the heading inputs 6e-8.
    assert np.abs(first - want[0]).max() < 1e-5 and np.abs(again - want[1]).max() < 1e-5
    assert np.abs(qpos[[1, 3]] - want[2][[1, 3]]).max() < 1e-6
    assert np.abs(lowest[[1, 3]]).max() < 1e-6  # each fighter's lowest point on the floor
    # The heading task's inputs, read from the worlds on the device.
    assert np.abs(heading[[1, 3]] - want[5][[1, 3]]).max() < 1e-6
    # The host's copy after the restarts: the restarted arenas as `reset` returned them, and the
    # others as stepped, not restarted (where the two physics part at touching soles, above).
    assert np.abs(observed[[1, 3]] - again).max() < 1e-5  # float64 on the host, float32 there
    assert np.abs(observed[[0, 2]] - first[[0, 2]]).max() > 1e-3


def test_a_world_out_of_contact_room_is_an_error_not_wrong_physics(monkeypatch):
    import models.arena.stepping.warp as warp_physics

    monkeypatch.setattr(warp_physics, "CONTACTS_PER_WORLD", 1)
    config = EnvConfig(num_envs=2, threads=1, stepping="warp", standing_share=1.0)
    with ArenaEnv(config, np.random.default_rng(0)) as env:
        assert isinstance(env._stepping.physics, WarpPhysics)
        q = env.model.qpos0
        zero = np.zeros((1, 34))
        env.reset([0, 1], ReferenceMotions(q[None, :35], zero, q[None, 35:], zero))
        with pytest.raises(warp_physics.WarpOverflow, match="ran out of room in world 0"):
            env.step(np.zeros((2, 2, 28)))
