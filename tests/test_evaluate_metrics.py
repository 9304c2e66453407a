"""The evaluation's measures on hand-built cases: W1, the style distances, punch accuracy and
error, time in guard; and evaluation bouts that repeat exactly and stop at a fall."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from models.pose.types import BLAZEPOSE_33
from tasks.dataset.labels import Punch
from tasks.dataset.statistics import FighterStatistics
from tasks.evaluate.metrics import (
    RATES,
    STYLE_DISTRIBUTIONS,
    distribution_distance,
    in_guard,
    punch_summary,
    rate_distance,
    score_punches,
    style_rows,
    wasserstein1,
)

INDEX = {name: i for i, name in enumerate(BLAZEPOSE_33)}


def test_w1_of_hand_computed_cases():
    # F_a is 1/2 on [0, 1), F_b steps to 1 at 0.5: |F_a - F_b| is 1/2 over a length of 1.
    assert wasserstein1([0.0, 1.0], [0.5]) == pytest.approx(0.5)
    # A shift moves every quantile by the shift.
    assert wasserstein1([0.0, 1.0, 2.0], [1.0, 2.0, 3.0]) == pytest.approx(1.0)
    # Unequal sizes: [0, 0, 3] against [1]: 2/3 of the mass moves 1, 1/3 moves 2.
    assert wasserstein1([3.0, 0.0, 0.0], [1.0]) == pytest.approx(4.0 / 3.0)
    assert wasserstein1([2.0], [2.0, 2.0]) == 0.0


def test_w1_matches_sorted_differences_for_equal_sizes():
    """For samples of one size, W1 is the mean distance between matching order statistics."""
    rng = np.random.default_rng(3)
    for n in (1, 5, 40):
        a, b = rng.normal(size=n), rng.normal(1.0, 2.0, size=n)
        expected = np.mean(np.abs(np.sort(a) - np.sort(b)))
        assert wasserstein1(a, b) == pytest.approx(expected, rel=1e-12)
        assert wasserstein1(b, a) == pytest.approx(expected, rel=1e-12)
    with pytest.raises(ValueError, match="non-empty"):
        wasserstein1([], [1.0])


def test_style_distances_are_bounded_and_zero_only_when_equal():
    assert distribution_distance([0.0], [5.0]) == pytest.approx(1.0)  # separate point masses
    assert distribution_distance([1.0, 2.0], [2.0, 1.0]) == 0.0
    assert distribution_distance([], []) == 0.0
    assert distribution_distance([], [1.0]) == 1.0
    rng = np.random.default_rng(0)
    for _ in range(20):
        a = rng.normal(rng.normal(), rng.uniform(0.1, 3), size=rng.integers(1, 30))
        b = rng.normal(rng.normal(), rng.uniform(0.1, 3), size=rng.integers(1, 30))
        assert 0.0 < distribution_distance(a, b) <= 1.0
    # Scale-free: the same pair in other units is at the same distance.
    a, b = rng.normal(size=10), rng.normal(0.5, 1.0, size=7)
    assert distribution_distance(a * 100, b * 100) == pytest.approx(distribution_distance(a, b))
    assert rate_distance(3.0, 1.0) == pytest.approx(2.0 / 3.0)
    assert rate_distance(0.0, 4.0) == 1.0
    assert rate_distance(0.0, 0.0) == 0.0
    # Below what the footage resolves (one event in 1.4 s is 43 per minute), rates are close.
    assert rate_distance(0.1, 0.0, resolution=43.0) == pytest.approx(0.1 / 43.0)
    assert rate_distance(120.0, 0.0, resolution=43.0) == 1.0


def _punch(hand: str, peak: int) -> Punch:
    return Punch(hand, "straight", peak, peak, peak, 0.5, np.zeros(3))


def test_punch_accuracy_and_error_on_a_hand_built_bout():
    frames = 3
    opponent = np.zeros((frames, 33, 3))
    for side, y in (("left", 0.08), ("right", -0.08)):
        opponent[:, INDEX[f"{side}_ear"]] = (1.0, y, 1.6)  # head centre (1, 0, 1.6)
        opponent[:, INDEX[f"{side}_shoulder"]] = (1.0, 2 * y, 1.45)
        opponent[:, INDEX[f"{side}_hip"]] = (1.0, y, 1.0)  # torso axis x = 1, z 1.0-1.45
    puncher = np.zeros((frames, 33, 3))
    puncher[0, INDEX["left_index"]] = (0.8, 0.0, 1.6)  # 0.20 from the head centre
    puncher[1, INDEX["right_index"]] = (0.6, 0.0, 1.6)  # 0.40 from it
    puncher[2, INDEX["right_index"]] = (0.83, 0.0, 1.2)  # 0.17 from the torso's axis
    punches = [_punch("left", 0), _punch("right", 1), _punch("right", 2)]
    scores = score_punches(
        punches, puncher, opponent, head_radius_m=0.1, torso_radius_m=0.12, radius_m=0.15
    )
    assert [s.target for s in scores] == ["head", "head", "torso"]
    assert [s.distance_m for s in scores] == pytest.approx([0.10, 0.30, 0.05])
    assert [s.accurate for s in scores] == [True, False, True]

    summary = punch_summary(scores)
    assert summary["punches_thrown"] == 3
    assert summary["punch_accuracy_pct"] == pytest.approx(200 / 3)  # eq 6.3
    assert summary["punch_accuracy_head_pct"] == pytest.approx(50.0)
    assert summary["punch_accuracy_torso_pct"] == pytest.approx(100.0)
    # eq 6.4-6.5: the MSE over x, y, z of the accurate punches' fist-to-target offsets.
    assert summary["punch_error_head_cm2"] == pytest.approx(10.0**2 / 3)
    assert summary["punch_error_torso_cm2"] == pytest.approx(5.0**2 / 3)
    assert summary["punch_error_cm2"] == pytest.approx((10.0**2 + 5.0**2) / 6)

    # A smaller sphere: nothing is accurate, and there is no error to average.
    tight = punch_summary(
        score_punches(
            punches, puncher, opponent, head_radius_m=0.1, torso_radius_m=0.12, radius_m=0.04
        )
    )
    assert tight["punch_accuracy_pct"] == 0.0 and "punch_error_cm2" not in tight
    assert punch_summary([]) == {
        "punches_thrown": 0.0,
        "punches_at_head": 0.0,
        "punches_at_torso": 0.0,
    }


def test_time_in_guard_needs_both_wrists_above_the_shoulders():
    k = np.zeros((3, 33, 3))
    k[:, INDEX["left_shoulder"], 2] = k[:, INDEX["right_shoulder"], 2] = 1.4
    k[:, INDEX["left_wrist"], 2] = [1.5, 1.5, 1.3]
    k[:, INDEX["right_wrist"], 2] = [1.5, 1.3, 1.3]
    assert in_guard(k).tolist() == [True, False, False]


def test_bouts_repeat_exactly_and_stop_at_a_fall(assets):
    from models.maaip.config import NetworkConfig
    from tasks.evaluate.bouts import simulate
    from tasks.evaluate.stage import untrained_policy
    from tasks.opponent.maaip import TorchPolicy
    from tasks.train.config import TrainConfig
    from tasks.train.data import clip_demonstrations

    demos = clip_demonstrations(assets, "punch")
    config = TrainConfig(network=NetworkConfig(hidden="16,16"))
    policy = untrained_policy(config, demos.reference)

    class Flail:
        def reset(self, seen) -> None:
            pass

        def act(self, seen) -> np.ndarray:
            return np.ones((len(seen.arenas), 28))  # every joint driven to its limit: it falls

    def run(seed: int):
        return simulate(
            (TorchPolicy(policy, 0), Flail()),
            reference=demos.reference,
            bones=demos.bones,
            env_config=config.env,
            episodes=3,
            frames=45,
            seed=seed,
        )

    first, again, other = run(0), run(0), run(1)
    assert np.array_equal(first.qpos, again.qpos, equal_nan=True)
    assert np.array_equal(first.damage, again.damage)
    assert not np.array_equal(first.start_frames, other.start_frames)
    assert (first.frames == first.steps + 1).all()  # nothing blew up
    ended = first.fell.any(axis=1)
    assert first.fell[:, 1].all() and not first.fell[:, 0].any()  # counted per fighter
    for e in range(first.episodes):
        assert np.isfinite(first.qpos[e, : first.frames[e]]).all()
        assert np.isnan(first.qpos[e, first.frames[e] :]).all()
        assert (first.steps[e] < 45) == ended[e]
    assert first.observations.shape[1:] == (2, 274) and math.isfinite(first.minutes)


def test_style_rows_compare_only_what_the_footage_resolves():
    def stats(minutes: float, punches: int, durations: list[float]) -> FighterStatistics:
        scalars = {name: 0.0 for name in RATES}
        scalars |= {"minutes": minutes, "orthodox_share": 0.5, "punches_per_min": punches / minutes}
        scalars["punches_per_min_left"] = scalars["punches_per_min_straight"] = punches / minutes
        samples = {name: np.array([1.0, 1.2]) for name in STYLE_DISTRIBUTIONS}
        samples["punch_duration_s"] = np.array(durations)
        return FighterStatistics(scalars, samples)

    footage = stats(1.4 / 60, 0, [])  # the demo's 1.4 s, no punch in it
    rows = {r.statistic: r for r in style_rows(stats(20.0, 2, [0.3, 0.4]), footage)}
    assert "punch_duration_s" not in rows  # nothing in the footage to compare with
    assert rows["punches_per_min"].distance == pytest.approx(0.1 / (60 / 1.4))
    boxed = stats(2.0, 60, [0.3] * 60)  # 30 punches per minute over 2 minutes of footage
    rows = {r.statistic: r for r in style_rows(stats(20.0, 0, []), boxed)}
    assert rows["punches_per_min"].distance == 1.0
    assert rows["punch_duration_s"].distance == 1.0  # thrown none where the footage has some


def test_bouts_start_standing_in_the_guard_and_a_still_guard_stays_up(assets):
    """Evaluation starts both fighters standing still in their guard where a reference frame
    places them, so a fall is the policy's, never a start-up one: the guard held still stays up
    for 4 s in every episode, from frames of the punch clip that training starts mid-motion."""
    from models.humanoid.stance import guard_pose
    from tasks.evaluate.bouts import simulate
    from tasks.opponent.still import StillGuard
    from tasks.train.config import TrainConfig
    from tasks.train.data import clip_demonstrations

    demos = clip_demonstrations(assets, "punch")
    ref = demos.reference
    guard = np.stack([guard_pose(demos.bones[0], ref.qpos0), guard_pose(demos.bones[1], ref.qpos1)])
    reference = dataclasses.replace(ref, stance=guard)
    config = TrainConfig().env
    bouts = simulate(
        (StillGuard(guard[0]), StillGuard(guard[1])),
        reference=reference,
        bones=demos.bones,
        env_config=config,
        episodes=6,
        frames=4 * config.policy_hz,
        seed=0,
    )
    first = bouts.qpos[:, 0]
    for agent, start in enumerate((0, 35)):
        np.testing.assert_allclose(first[:, start + 7 : start + 35], np.tile(guard[agent], (6, 1)))
    assert not bouts.fell.any() and (bouts.steps == 4 * config.policy_hz).all()


def test_footage_is_labelled_as_a_fighter_and_rated_per_window(assets):
    """`footage_bouts` lays footage in the arena so `label_fighter` reads it as a simulated
    fighter; `window_rates` counts each 1-s window's punches and steps; `rate_interval` gives
    their mean and its bootstrap interval. DeepMimic's punch three times over (its partner
    0.7 m ahead) and its walk four times (3 m ahead)."""
    import mujoco
    from opponents import facing

    from models.arena.mjcf import arena_index, arena_mjcf
    from models.humanoid.boxer import BoneLengths
    from tasks.dataset.config import PunchConfig
    from tasks.deepmimic import clip_path, load_deepmimic, retarget
    from tasks.evaluate.metrics import footage_bouts, label_fighter, rate_interval, window_rates

    punch, walk = (
        np.concatenate([retarget(load_deepmimic(clip_path(assets, n)))] * k)
        for n, k in (("punch", 3), ("walk", 4))
    )
    model = mujoco.MjModel.from_xml_string(arena_mjcf((BoneLengths(), BoneLengths())))
    clips = [(punch, facing(punch, 0.7)), (walk, facing(walk, 3.0))]
    bouts = footage_bouts(model, clips, 30)
    index = arena_index(model)
    assert list(bouts.frames) == [len(punch), len(walk)] and bouts.policy_hz == 30
    np.testing.assert_array_equal(bouts.qpos[1, : len(walk)][:, index.agents[0].qpos], walk)
    np.testing.assert_array_equal(bouts.qpos[0, : len(punch)][:, index.agents[1].qpos], clips[0][1])
    assert np.isnan(bouts.qpos[1, len(walk) :]).all()

    fighter = label_fighter(bouts, 0, model=model, bones=BoneLengths(), punch=PunchConfig())
    peaks = [p.peak for p in fighter.punches[0]]
    # The one punch of the clip, once in each copy (65 frames); the walk throws none and steps.
    assert len(peaks) == 3 and set(np.diff(peaks)) == {65} and not fighter.punches[1]
    assert len(fighter.steps[1]) >= 4

    rates = window_rates(fighter, bouts, 1.0)
    windows = [len(punch) // 30, len(walk) // 30]  # whole windows only: 6 and 5
    assert [len(v) for v in rates.values()] == [sum(windows)] * 2
    expected = np.zeros(sum(windows))
    for peak in peaks:
        if peak < windows[0] * 30:
            expected[peak // 30] += 60.0
    np.testing.assert_array_equal(rates["punches_per_min"], expected)
    stepped = [s.touch_down for e in (0, 1) for s in fighter.steps[e]]
    assert rates["steps_per_min"].sum() / 60 <= len(stepped)

    mean, low, high = rate_interval(rates["steps_per_min"], seed=0)
    assert mean == rates["steps_per_min"].mean()
    assert rates["steps_per_min"].min() <= low <= mean <= high <= rates["steps_per_min"].max()
    assert rate_interval(rates["steps_per_min"], seed=0) == (mean, low, high)
    assert rate_interval(np.full(4, 60.0), seed=0) == (60.0, 60.0, 60.0)
    with pytest.raises(ValueError, match="no windows"):
        rate_interval(np.zeros(0), seed=0)
