"""The held-out two-sample classifier test (tasks/evaluate/two_sample.py): against Gaussians
whose AUC is known, against scipy's Mann-Whitney U, on retargeted DeepMimic motion (walk
against walk, against run and against a still guard), and as the evaluate stage assembles it."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from scipy.stats import mannwhitneyu, norm

from models.arena.mjcf import arena_index, arena_mjcf
from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.kinematics import NQ, axis_angle_matrix, matrix_to_quat, quat_to_matrix
from models.humanoid.stance import guard_pose
from tasks import deepmimic
from tasks.dataset.store import FootageClip
from tasks.evaluate.bouts import Bouts
from tasks.evaluate.stage import NO_HELD_OUT, NO_TRACKER, two_sample_rows
from tasks.evaluate.two_sample import (
    FEATURES,
    FOLDS,
    WINDOW_FEATURES,
    _fit_logistic,
    auc,
    bout_windows,
    classifier_test,
    feature_gap,
    footage_windows,
    frame_features,
    gap_closed,
    telltales,
    window_features,
)

FPS = 30.0
FRAMES = round(FPS)  # one window
BONES = BoneLengths()
COLUMN = {name: i for i, name in enumerate(FEATURES)}
MODEL = mujoco.MjModel.from_xml_string(boxer_mjcf(BONES))  # the default body, alone


def gaussians(n: int, dims: int, shift: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """n standard normal vectors of each side, the second's first coordinate moved by shift."""
    rng = np.random.default_rng(seed)
    real, fake = rng.normal(size=(n, dims)), rng.normal(size=(n, dims))
    fake[:, 0] += shift
    return real, fake


# --------------------------------------------------------------------------
# The test against known answers
# --------------------------------------------------------------------------


def test_auc_is_the_mann_whitney_u_over_the_pairs_ties_counting_half():
    rng = np.random.default_rng(0)
    real = rng.integers(0, 5, 40).astype(float)  # many ties
    fake = rng.integers(0, 4, 30).astype(float)
    u = mannwhitneyu(real, fake).statistic
    assert auc(real, fake) == pytest.approx(u / (40 * 30))
    assert auc([2.0, 3.0], [0.0, 1.0]) == 1.0 and auc([1.0], [1.0]) == 0.5


def test_windows_from_one_distribution_give_an_interval_around_one_half():
    result = classifier_test(*gaussians(100, 10, 0.0, seed=1), seed=0)
    assert result.low < 0.5 < result.high
    assert (result.n_real, result.n_fake) == (100, 100)


def test_separable_windows_score_near_one():
    result = classifier_test(*gaussians(50, 10, 6.0, seed=2), seed=0)
    assert result.auc > 0.99 and result.low > 0.95


@pytest.mark.parametrize("shift", [0.5, 1.0, 1.5])
def test_shifted_gaussians_give_the_analytic_auc(shift):
    """Two unit Gaussians a distance d apart along one axis: the best score's AUC is
    P(X - Y > 0) = Phi(d / sqrt 2). Four more axes of pure noise cost the fitted classifier a
    little; with 400 windows a side the AUC's standard error is about 0.015, so within 0.04."""
    real, fake = gaussians(400, 5, shift, seed=3)
    result = classifier_test(fake, real, seed=0)  # the shifted side as the real one: AUC > 0.5
    analytic = norm.cdf(shift / math.sqrt(2))
    assert result.auc == pytest.approx(analytic, abs=0.04)
    assert result.low <= analytic <= result.high
    assert result.high - result.low < 0.1


def test_a_seed_gives_the_same_result_to_the_bit():
    real, fake = gaussians(60, 8, 0.8, seed=4)
    assert classifier_test(real, fake, seed=7) == classifier_test(real, fake, seed=7)
    assert classifier_test(real, fake, seed=7) != classifier_test(real, fake, seed=8)


def test_scores_are_held_out_where_an_in_sample_fit_would_be_perfect():
    """200 dimensions of noise and 20 windows a side: any classifier fitted on all 40 windows
    separates them (in-sample AUC 1); the held-out scores cannot."""
    real, fake = gaussians(20, 200, 0.0, seed=5)
    x = np.concatenate([real, fake])
    w, b = _fit_logistic(x, np.r_[np.ones(20), np.zeros(20)], np.ones(40), 1.0)
    assert auc(real @ w + b, fake @ w + b) == 1.0
    result = classifier_test(real, fake, seed=0)
    assert result.auc < 0.75 and result.low < 0.5


def test_too_few_windows_or_bad_ones_are_refused():
    real, fake = gaussians(FOLDS, 3, 0.0, seed=6)
    classifier_test(real, fake, seed=0)  # the least the test makes do with
    with pytest.raises(ValueError, match="real_windows has 4 windows.*at least folds = 5"):
        classifier_test(real[:4], fake, seed=0)
    with pytest.raises(ValueError, match="fake_windows has 2 windows"):
        classifier_test(real, fake[:2], seed=0)
    with pytest.raises(ValueError, match="one D"):
        classifier_test(real, fake[:, :2], seed=0)
    with pytest.raises(ValueError, match="finite"):
        classifier_test(np.where(real > 1, np.nan, real), fake, seed=0)
    with pytest.raises(ValueError, match="folds must be an integer >= 2"):
        classifier_test(real, fake, seed=0, folds=1)


def test_telltales_name_the_features_that_differ_most_in_pooled_standard_deviations():
    rng = np.random.default_rng(0)
    real = rng.normal(size=(40, len(WINDOW_FEATURES)))
    simulated = rng.normal(size=(40, len(WINDOW_FEATURES)))
    simulated[:, 7] += 3.0  # the simulated fighter's eighth feature sits 3 deviations higher
    simulated[:, 2] -= 1.5
    real[:, 5] = simulated[:, 5] = 0.0  # constant on both sides: no difference, not NaN
    said = telltales(real, simulated).split(", ")
    assert len(said) == 3
    assert said[0].startswith(f"{WINDOW_FEATURES[7]} -") and said[1].startswith(WINDOW_FEATURES[2])
    d = float(said[0].rsplit(" ", 1)[1])
    pooled = np.sqrt(0.5 * (real[:, 7].var() + simulated[:, 7].var()))
    assert d == pytest.approx((real[:, 7].mean() - simulated[:, 7].mean()) / pooled, abs=0.005)


def test_gap_closed_is_the_share_of_the_still_to_replay_gap():
    assert gap_closed(0.7, 1.0, 0.6) == pytest.approx(0.75)
    assert gap_closed(1.0, 1.0, 0.6) == 0.0 and gap_closed(0.6, 1.0, 0.6) == 1.0
    assert gap_closed(1.05, 1.0, 0.6) == pytest.approx(-0.125)  # worse than standing still
    assert gap_closed(0.7, None, 0.6) is None and gap_closed(None, 1.0, 0.6) is None
    assert gap_closed(0.7, 1.0, None) is None
    assert gap_closed(0.7, 0.6, 0.6) is None  # no gap to close


# --------------------------------------------------------------------------
# Features of a fighter's motion
# --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def clips(assets) -> dict[str, np.ndarray]:
    return {
        name: deepmimic.retarget(deepmimic.load_deepmimic(deepmimic.clip_path(assets, name)))
        for name in ("walk", "run")
    }


def ahead(qpos: np.ndarray, metres: float = 1.5) -> np.ndarray:
    """(T, 3) a partner ``metres`` in front of the clip's root along +x, where the walk and the
    run head: the distance and bearing of two fighters moving together."""
    return qpos[:, :3] + np.array([metres, 0.0, 0.0])


def segments(qpos: np.ndarray, count: int, seed: int, jitter: float = 0.01) -> np.ndarray:
    """(count, D) windows of a looped clip (its last frame the first of the next cycle, the root
    carried on), each from a 1 s segment of its own: a random phase, a tempo within 10 % and
    N(0, jitter) rad on every hinge, so that the windows are independent draws of that motion.
    (Windows cut every second from one long loop are not: their phases repeat at the clip's
    period, and the held-out AUC of two such sets falls below 0.5, to 0.34-0.37 measured.)"""
    rng = np.random.default_rng(seed)
    period = len(qpos) - 1
    step = np.r_[qpos[-1, :2] - qpos[0, :2], np.zeros(NQ - 2)]
    loop = np.concatenate([qpos[:-1] + k * step for k in range(4)])
    found = []
    for _ in range(count):
        at = rng.uniform(0, period) + rng.uniform(0.9, 1.1) * np.arange(FRAMES)
        q = np.column_stack([np.interp(at, np.arange(len(loop)), c) for c in loop.T])
        q[:, 3:7] /= np.linalg.norm(q[:, 3:7], axis=1, keepdims=True)
        q[:, 7:] += rng.normal(0.0, jitter, q[:, 7:].shape)
        found.append(window_features(MODEL, q, ahead(q), fps=FPS))
    return np.concatenate(found)


def still_guard(qpos: np.ndarray, frames: int) -> np.ndarray:
    """(frames, 35) the default body holding the guard `guard_pose` finds for the clip's
    frames, standing still at the origin facing +x."""
    pose = np.r_[0.0, 0.0, qpos[0, 2], 1.0, 0.0, 0.0, 0.0, guard_pose(BONES, qpos)]
    return np.tile(pose, (frames, 1))


def test_frame_features_measure_what_they_name(clips):
    walk = clips["walk"]
    features = frame_features(MODEL, walk, ahead(walk), fps=FPS)
    assert features.shape == (len(walk), len(FEATURES)) == (39, 60)
    assert np.allclose(features[:, :28], walk[:, 7:])
    assert np.allclose(features[:, COLUMN["root_height"]], walk[:, 2])
    # The partner 1.5 m along +x, the walker facing about +x (its yaw sways by 0.13 rad).
    assert np.allclose(features[:, COLUMN["distance"]], 1.5)
    assert np.all(features[:, COLUMN["bearing_cos"]] > math.cos(0.14))
    # The root moves 1.32 m in 38 frames: about 1.04 m/s forwards, in the heading frame.
    speed = features[5:-5, COLUMN["root_velocity_x"]].mean()
    assert speed == pytest.approx(1.318 / (38 / FPS), rel=0.05)
    # Hands hang beside the pelvis, feet below it.
    assert np.all(features[:, COLUMN["left_hand_y"]] > 0) and np.all(
        features[:, COLUMN["right_hand_y"]] < 0
    )
    assert np.all(features[:, COLUMN["left_foot_z"]] < -0.6)


def test_frame_features_ignore_where_the_fighters_stand_and_face(clips):
    """Turning and moving both fighters together changes no feature."""
    walk = clips["walk"]
    turn = axis_angle_matrix((0.0, 0.0, 1.0), 2.0)
    moved = walk.copy()
    moved[:, :3] = walk[:, :3] @ turn.T + np.array([3.0, -2.0, 0.0])
    moved[:, 3:7] = matrix_to_quat(turn @ quat_to_matrix(walk[:, 3:7]))
    other = ahead(walk) @ turn.T + np.array([3.0, -2.0, 0.0])
    assert np.allclose(
        frame_features(MODEL, moved, other, fps=FPS),
        frame_features(MODEL, walk, ahead(walk), fps=FPS),
        atol=1e-9,
    )


def test_windows_summarise_each_second_by_its_mean_and_spread(clips):
    walk = clips["walk"]
    windows = window_features(MODEL, walk, ahead(walk), fps=FPS)
    assert windows.shape == (1, len(WINDOW_FEATURES)) == (1, 120)  # 39 frames: one window
    features = frame_features(MODEL, walk, ahead(walk), fps=FPS)
    assert np.allclose(windows[0, :60], features[:30].mean(axis=0))
    assert np.allclose(windows[0, 60:], features[:30].std(axis=0))
    overlapping = window_features(MODEL, walk, ahead(walk), fps=FPS, stride_s=0.25)
    assert len(overlapping) == 2  # 0.25 s is 8 frames: windows from frames 0 and 8
    assert np.allclose(overlapping[1, :60], features[8:38].mean(axis=0))
    assert window_features(MODEL, walk[:29], ahead(walk[:29]), fps=FPS).shape == (0, 120)


def test_walk_against_walk_cannot_be_told_apart(clips):
    result = classifier_test(
        segments(clips["walk"], 60, seed=1), segments(clips["walk"], 60, seed=2), seed=0
    )
    assert result.low < 0.5 < result.high
    assert abs(result.auc - 0.5) < 0.15


def test_walk_against_a_still_guard_and_against_a_run_is_told_apart(clips):
    walk = segments(clips["walk"], 40, seed=3)
    guard = still_guard(clips["walk"], 40 * FRAMES)
    still = window_features(MODEL, guard, ahead(guard), fps=FPS)
    assert len(still) == 40
    against_still = classifier_test(walk, still, seed=0)
    assert against_still.auc >= 0.95 and against_still.low >= 0.95
    against_run = classifier_test(walk, segments(clips["run"], 40, seed=4), seed=0)
    assert against_run.auc >= 0.95


# --------------------------------------------------------------------------
# As the evaluate stage makes it
# --------------------------------------------------------------------------


def arena_bouts(qpos0: list[np.ndarray], qpos1: list[np.ndarray]) -> Bouts:
    """Bouts recorded by hand: episode e has agent 0 at qpos0[e] and agent 1 at qpos1[e]."""
    frames = np.array([len(q) for q in qpos0])
    qpos = np.full((len(qpos0), frames.max(), 2 * NQ), np.nan)
    for e, (a, b) in enumerate(zip(qpos0, qpos1, strict=True)):
        qpos[e, : len(a)] = np.concatenate([a, b], axis=1)
    zeros = np.zeros((len(frames), 2))
    return Bouts(
        qpos=qpos,
        frames=frames,
        steps=frames - 1,
        damage=zeros,
        fell=zeros.astype(bool),
        unstable=np.zeros(len(frames), dtype=bool),
        start_frames=np.zeros(len(frames), dtype=int),
        observations=np.zeros((0, 2, 274)),
        tasks=None,
        task_return=None,
        policy_hz=int(FPS),
    )


def test_bouts_and_footage_of_one_motion_give_the_same_windows(clips):
    """The simulated side (an arena, two prefixed fighters) and the footage's (a lone boxer of
    the fighter's bones) measure the same motion the same."""
    arena = mujoco.MjModel.from_xml_string(arena_mjcf((BONES, BONES)))
    index = arena_index(arena)
    assert [a.qpos for a in index.agents] == [slice(0, NQ), slice(NQ, 2 * NQ)]
    walk, run = clips["walk"], clips["run"]
    guard = still_guard(walk, len(run))
    guard[:, 0] = 2.0
    bouts = arena_bouts([walk, run], [np.tile(guard[0], (len(walk), 1)), guard])
    footage = footage_windows(
        [(walk, np.tile(guard[0], (len(walk), 1)), BONES), (run, guard, BONES)], FPS
    )
    assert len(footage) == 1  # the run's 25 frames are short of a window
    assert np.allclose(bout_windows(arena, bouts, 0), footage)
    assert bout_windows(arena, bouts, 1).shape == (1, 120)


def test_the_stage_rows_hold_the_auc_or_null_and_why(clips):
    walk = clips["walk"]
    heldout = (
        FootageClip("video", q := np.concatenate([walk] * 4), np.tile(q[0], (len(q), 1)), BONES),
    )
    real = footage_windows([(c.qpos, c.other_qpos, c.bones) for c in heldout], FPS)  # 5 windows
    rng = np.random.default_rng(0)
    simulated = {
        "adversary": rng.normal(size=(20, 120)),
        "untrained": rng.normal(size=(3, 120)),
        "still": np.zeros((20, 120)),
    }
    references = {"footage": real, "replay": NO_TRACKER}
    levels = {"footage": np.concatenate([real] * 2), "replay": NO_TRACKER}
    rows, metrics = two_sample_rows(references, levels, simulated, seed=0)
    by = {(row.reference, row.policy): row for row in rows}
    assert list(by) == [
        *(("footage", p) for p in (*simulated, "replay", "train")),
        *(("replay", p) for p in (*simulated, "train")),
    ]
    adversary = by["footage", "adversary"]
    assert (adversary.real_windows, adversary.simulated_windows, adversary.reason) == (5, 20, None)
    assert adversary.telltales == telltales(real, simulated["adversary"])
    assert adversary.feature_gap == feature_gap(real, simulated["adversary"])
    assert adversary.auc_low <= adversary.auc <= adversary.auc_high
    assert metrics["two_sample_auc"] == adversary.auc
    assert metrics["two_sample_auc_low"] == adversary.auc_low
    assert metrics["feature_gap"] == adversary.feature_gap
    untrained = by["footage", "untrained"]
    assert (untrained.auc, untrained.auc_low, untrained.auc_high) == (None, None, None)
    assert untrained.telltales is None and untrained.feature_gap is None
    assert (untrained.real_windows, untrained.simulated_windows) == (5, 3)
    assert "the bouts give 3 windows" in untrained.reason
    assert "two_sample_auc_untrained" not in metrics
    assert metrics["two_sample_auc_still"] == by["footage", "still"].auc
    # The real-against-real level: the train footage (here the held-out windows twice).
    level = by["footage", "train"]
    assert metrics["two_sample_auc_train"] == level.auc and level.feature_gap == pytest.approx(0)
    replay = by["footage", "replay"]
    assert (replay.auc, replay.real_windows, replay.simulated_windows) == (None, 5, 0)
    assert replay.reason == NO_TRACKER
    assert all(by["replay", p].reason == NO_TRACKER for p in (*simulated, "train"))
    # Nothing replayed: neither gap has an end.
    assert "two_sample_gap_closed" not in metrics and "feature_gap_closed" not in metrics
    assert not any("vs_replay" in name for name in metrics)

    # A replay measured: the share of the gap between still and replay the adversary closes,
    # on the AUC and on the feature gap; every fighter judged against the replay as well.
    close = np.concatenate([real] * 4) * rng.normal(1.0, 0.01, size=(20, real.shape[1]))
    replayed = {"footage": real, "replay": close}
    rows, metrics = two_sample_rows(
        replayed, {"footage": real, "replay": close[:10]}, simulated, seed=0
    )
    by = {(row.reference, row.policy): row for row in rows}
    replay = by["footage", "replay"]
    assert replay.reason is None and replay.simulated_windows == 20
    assert metrics["two_sample_auc_replay"] == replay.auc
    assert replay.auc < metrics["two_sample_auc_still"]
    assert metrics["two_sample_gap_closed"] == pytest.approx(
        gap_closed(metrics["two_sample_auc"], metrics["two_sample_auc_still"], replay.auc)
    )
    assert metrics["feature_gap_closed"] == pytest.approx(
        gap_closed(metrics["feature_gap"], metrics["feature_gap_still"], replay.feature_gap)
    )
    against = by["replay", "adversary"]
    assert (against.real_windows, against.simulated_windows) == (20, 20)
    assert metrics["two_sample_auc_vs_replay"] == against.auc
    assert against.feature_gap == feature_gap(close, simulated["adversary"])
    assert metrics["two_sample_auc_vs_replay_train"] == by["replay", "train"].auc
    assert by["replay", "untrained"].reason.startswith("the bouts give 3 windows")

    rows, _ = two_sample_rows(
        {"footage": real, "replay": np.zeros((4, 120))}, levels, simulated, seed=0
    )
    by = {(row.reference, row.policy): row for row in rows}
    assert by["footage", "replay"].reason == "the replay gives 4 windows of 1 s; the test needs 5"
    assert by["replay", "still"].reason == by["footage", "replay"].reason
    rows, _ = two_sample_rows(
        references, {"footage": real[:2], "replay": NO_TRACKER}, simulated, seed=0
    )
    by = {(row.reference, row.policy): row for row in rows}
    assert (
        by["footage", "train"].reason
        == "the train footage gives 2 windows of 1 s; the test needs 5"
    )

    rows, metrics = two_sample_rows(
        {"footage": NO_HELD_OUT, "replay": NO_TRACKER}, levels, simulated, seed=0
    )
    assert metrics == {} and all(row.auc is None for row in rows)
    assert rows[0].reason.startswith("no held-out footage")
    short = footage_windows([(walk, np.tile(walk[0], (len(walk), 1)), BONES)], FPS)
    rows, _ = two_sample_rows({"footage": short, "replay": NO_TRACKER}, levels, simulated, seed=0)
    assert rows[0].reason == "the held-out footage gives 1 window of 1 s; the test needs 5"


def test_the_feature_gap_is_the_mean_standardised_difference_of_means():
    rng = np.random.default_rng(3)
    reference = rng.normal([0.0, 10.0, 5.0], [1.0, 2.0, 0.0], size=(400, 3))
    reference[:, 2] = 5.0  # constant over the reference: no scale, left out
    moved = reference + [0.5, -4.0, 7.0]
    sd = reference[:, :2].std(axis=0)
    assert feature_gap(reference, moved) == pytest.approx((0.5 / sd[0] + 4.0 / sd[1]) / 2)
    assert feature_gap(reference, reference) == 0.0
    # Graded where the AUC saturates: both told apart (nearly) always, one twice as far.
    far, further = reference + [6.0, 0, 0], reference + [12.0, 0, 0]
    for moved_far in (far, further):
        assert classifier_test(reference, moved_far, seed=0).auc > 0.9999
    assert feature_gap(reference, further) == pytest.approx(2 * feature_gap(reference, far))
    with pytest.raises(ValueError, match="constant in every feature"):
        feature_gap(np.ones((5, 3)), moved)
    with pytest.raises(ValueError, match="non-empty"):
        feature_gap(reference, np.zeros((0, 3)))
    with pytest.raises(ValueError, match="finite"):
        feature_gap(reference, np.full((2, 3), np.nan))


def test_the_cli_says_each_reference_its_level_and_the_gaps_closed(clips):
    """`classifier_lines`: a line against the footage (with the train footage's level and the
    share of the gap closed), one for the feature gap, one against the replay."""
    import dataclasses

    from flows.cli.tables import classifier_lines

    walk = clips["walk"]
    real = footage_windows([(np.concatenate([walk] * 4), np.tile(walk[0], (156, 1)), BONES)], FPS)
    rng = np.random.default_rng(1)
    close = np.concatenate([real] * 4) * rng.normal(1.0, 0.01, size=(20, real.shape[1]))
    simulated = {
        "adversary": close[:10] * 1.05,
        "untrained": NO_TRACKER,
        "still": np.zeros((8, 120)),
    }
    rows, metrics = two_sample_rows(
        {"footage": real, "replay": close}, {"footage": real, "replay": close}, simulated, seed=0
    )
    lines = classifier_lines([dataclasses.asdict(r) for r in rows], metrics)
    by = {(r.reference, r.policy): r for r in rows}
    assert len(lines) == 3
    footage, gaps, replay = lines
    assert f"trained {by['footage', 'adversary'].auc:.2f} [" in footage
    assert (
        f"its own train split (real against real) {metrics['two_sample_auc_train']:.2f}" in footage
    )
    assert "untrained" not in footage  # not measured: no row to show
    assert f"the trained adversary closes {100 * metrics['two_sample_gap_closed']:.0f} %" in footage
    assert f"standing still {metrics['feature_gap_still']:.2f}" in gaps
    assert f"closes {100 * metrics['feature_gap_closed']:.0f} % of the gap" in gaps
    assert replay.startswith("  against the replay: trained ")
    assert f"{metrics['two_sample_auc_vs_replay_train']:.2f}" in replay
    none = two_sample_rows(
        {"footage": NO_HELD_OUT, "replay": NO_TRACKER},
        {"footage": real, "replay": NO_TRACKER},
        simulated,
        seed=0,
    )[0]
    lines = classifier_lines([dataclasses.asdict(r) for r in none], {})
    assert lines[0].endswith(f"told apart: not measured ({NO_HELD_OUT})")
    assert lines[1] == f"  against the replay: not measured ({NO_TRACKER})"
