"""Does the simulated fighter move like the footage? A held-out two-sample classifier test.

The headline figure of the evaluation (issue 32): a fresh small classifier learns to tell
1-second windows of the adversary's held-out footage from 1-second windows of a simulated
fighter, and its area under the ROC curve (AUC), measured only on windows it never saw, says how
well it can: 0.5 is "cannot tell them apart", 1 is "never wrong". The same test of the fighter
standing still in its guard and of the untrained policy gives the scale: a policy earns the
claim only where its AUC is well below the still guard's. This is the classifier two-sample
test (C2ST; Lopez-Paz & Oquab, "Revisiting classifier two-sample tests", ICLR 2017), with the
AUC of held-out scores as its statistic rather than the accuracy.

Per frame (`frame_features`, F = 60 numbers, all invariant to where the fighter stands and which
way it faces, so that the simulated arena's world frame and the footage's camera do not matter):

- the 28 hinge angles (the actuated qpos, kinematics' `JOINT_LAYOUT` order);
- hands and feet (`right_hand`, `left_hand`, `right_foot`, `left_foot`: the wrists and ankles)
  relative to the root in the root's heading frame (`local_body_positions`), 12, and the root's
  height, 1 (a fighter crouching or falling);
- the horizontal distance to the other fighter's root and its bearing in the heading frame, as
  cos and sin (no jump at +-pi), 3;
- low-passed velocities: the root's in the heading frame (3), its yaw rate (1) and the hands'
  and feet's relative to the root in the heading frame (12), 16. Each is a central difference
  then a zero-phase 4th-order Butterworth low-pass (`scipy.signal.sosfiltfilt`) at
  `VELOCITY_CUTOFF_HZ` = 6 Hz, over each unbroken segment of motion. 6 Hz is the cutoff
  biomechanics commonly uses for whole-body movement kinematics (Winter, "Biomechanics and Motor
  Control of Human Movement", 4th ed., 2009, ch. 2): it keeps the movement (a punch's extension
  takes 0.15-0.3 s) and removes most of the lifting's frame-to-frame jitter, which
  differentiation amplifies and which would otherwise let the classifier tell footage from
  physics by its noise rather than by how the fighter moves.

Per window (`window_features`): `WINDOW_S` = 1 s of frames, taken every `WINDOW_S` (no overlap),
summarised by each feature's mean and standard deviation over the window, D = 2 F = 120
numbers: where the body is on average and how much it moves. A fixed short vector suits a
linear classifier fitted on few footage windows (a subsampled sequence would be 30 F numbers
and depend on the phase of each movement within the window). Windows do not overlap because an
overlapping window would have near-copies in the folds the classifier trains on, and the
bootstrap would count correlated windows as independent.

The test (`classifier_test`): L2-regularised logistic regression on standardised window vectors
(`scipy.optimize.minimize`, L-BFGS), the two classes weighted equally, cross-fitted over
stratified k folds: each window's score comes from the model fitted on the other folds, the
standardisation too, so every score is held out. The AUC of the scores is the Mann-Whitney U
over n_real n_fake; its 95 % interval a percentile bootstrap resampling the windows of each class
(the fitted scores kept: the interval covers the windows' sampling, not the refits'). A linear
classifier can only find differences in the windows' means and spreads, so the AUC is a lower
bound on what a stronger one could find; it is the figure the must-show asks of a fresh small
classifier.

The held-out AUC assumes the windows of each side are like independent draws. A motion that
repeats exactly (a looped clip cut every second) breaks that: each window's near-copies fill the
training folds of the other side more than its own, and such a set tested against itself scores
below 0.5 (0.34-0.37 on DeepMimic's walk looped 80 times). An interval below 0.5 says "not told
apart", never "more like the footage than the footage".

A graded figure beside the AUC (`feature_gap`): the mean, over the window features, of the
absolute difference between the two sides' means in the reference windows' standard deviations.
The AUC saturates at 1 once any one feature tells the sides apart (the tracker's replay scored
1.00 on its ankles alone); the feature gap keeps falling as more of the motion comes right.

`gap_closed` gives the share of the gap between the still guard and the tracker replaying the
footage that a policy closes, on either figure.

Shape letters: T frames, F per-frame features, W windows, D = 2 F.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.optimize import minimize
from scipy.signal import butter, sosfiltfilt
from scipy.stats import rankdata

from models.arena.mjcf import DEFAULT_PREFIXES
from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.compiled import forward_kinematics_batch, humanoid_index
from models.humanoid.kinematics import (
    BODY_NAMES,
    HINGE_NAMES,
    ROOT_POS,
    ROOT_QUAT,
    heading_yaw,
    local_body_positions,
    to_heading_frame,
)
from models.tracking.gate import Played
from tasks.evaluate.bouts import Bouts

WINDOW_S = 1.0  # a window's length, and the stride between windows (no overlap)
VELOCITY_CUTOFF_HZ = 6.0  # the velocities' low-pass (module docstring)
FILTER_ORDER = 4
FOLDS = 5
BOOTSTRAP = 1000
TELLTALES = 3  # the features `telltales` names
L2 = 1.0  # the weights' penalty, l2 / 2 |w|^2, against a log-loss summed over n windows
LEVEL = 0.95

# Hands and feet: the bodies whose origins are the wrists and ankles.
LIMBS: tuple[str, ...] = ("right_hand", "left_hand", "right_foot", "left_foot")
_LIMBS = np.array([BODY_NAMES.index(b) for b in LIMBS])


def _xyz(name: str) -> tuple[str, ...]:
    return tuple(f"{name}_{axis}" for axis in "xyz")


# The per-frame features, in `frame_features`' column order.
FEATURES: tuple[str, ...] = (
    *HINGE_NAMES,
    *(f for limb in LIMBS for f in _xyz(limb)),
    "root_height",
    "distance",
    "bearing_cos",
    "bearing_sin",
    *_xyz("root_velocity"),
    "yaw_rate",
    *(f for limb in LIMBS for f in _xyz(f"{limb}_velocity")),
)
# The window vector's entries, in `window_features`' column order.
WINDOW_FEATURES: tuple[str, ...] = (
    *(f"{f}_mean" for f in FEATURES),
    *(f"{f}_std" for f in FEATURES),
)


# --------------------------------------------------------------------------
# Features
# --------------------------------------------------------------------------


def low_pass(values: np.ndarray, fps: float, cutoff_hz: float = VELOCITY_CUTOFF_HZ) -> np.ndarray:
    """``values`` (T, ...) through a zero-phase Butterworth low-pass along time (order
    `FILTER_ORDER`, run forwards and backwards); T must exceed 3 (2 sections + 1) = 15 frames,
    scipy's padding."""
    if not 0 < cutoff_hz < fps / 2:
        raise ValueError(f"cutoff_hz must be in (0, fps / 2 = {fps / 2}), got {cutoff_hz}")
    sos = butter(FILTER_ORDER, cutoff_hz, fs=fps, output="sos")
    return sosfiltfilt(sos, np.asarray(values, dtype=np.float64), axis=0)


def frame_features(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    other_root: np.ndarray,
    *,
    prefix: str = "",
    fps: float,
    cutoff_hz: float = VELOCITY_CUTOFF_HZ,
) -> np.ndarray:
    """(T, F) per-frame features (`FEATURES`, module docstring) of one unbroken segment.

    Args:
        model: a compiled model holding the fighter (a lone `boxer_mjcf` of its bones, or the
            arena it fought in).
        qpos: (T, model.nq) the model's configurations, T > 15 (the low-pass's padding).
        other_root: (T, 3) the other fighter's root position, world frame.
        prefix: the fighter's name prefix in ``model``.
        fps: frames per second.
        cutoff_hz: the velocities' low-pass cutoff.
    """
    q = np.asarray(qpos, dtype=np.float64)
    other = np.asarray(other_root, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != model.nq:
        raise ValueError(f"qpos must have shape (T, nq={model.nq}), got {q.shape}")
    if other.shape != (len(q), 3):
        raise ValueError(f"other_root must have shape (T={len(q)}, 3), got {other.shape}")
    if not (np.isfinite(q).all() and np.isfinite(other).all()):
        raise ValueError("qpos and other_root must be finite")
    if not (isinstance(fps, int | float) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    own = q[:, humanoid_index(model, prefix=prefix).qpos]
    root_pos, root_quat = own[:, ROOT_POS], own[:, ROOT_QUAT]
    body_pos, _ = forward_kinematics_batch(model, q, prefix=prefix)
    limbs = local_body_positions(body_pos[:, _LIMBS], root_pos, root_quat)
    toward = other - root_pos
    toward[:, 2] = 0.0
    ahead = to_heading_frame(toward[:, None], root_quat)[:, 0]
    bearing = np.arctan2(ahead[:, 1], ahead[:, 0])
    dt = 1.0 / fps
    root_velocity = to_heading_frame(np.gradient(root_pos, dt, axis=0)[:, None], root_quat)[:, 0]
    yaw_rate = np.gradient(np.unwrap(heading_yaw(root_quat)), dt)
    limb_velocity = np.gradient(limbs, dt, axis=0).reshape(len(q), -1)
    velocities = low_pass(np.column_stack([root_velocity, yaw_rate, limb_velocity]), fps, cutoff_hz)
    return np.column_stack(
        [
            own[:, 7:],
            limbs.reshape(len(q), -1),
            root_pos[:, 2],
            np.linalg.norm(toward, axis=1),
            np.cos(bearing),
            np.sin(bearing),
            velocities,
        ]
    )


def summarise_windows(features: np.ndarray, *, frames: int, stride: int) -> np.ndarray:
    """(W, 2 F) each window's per-feature mean, then standard deviation, of per-frame features
    (T, F): windows of ``frames`` frames starting every ``stride`` frames, W = 0 when T <
    ``frames``."""
    x = np.asarray(features, dtype=np.float64)
    if x.ndim != 2:
        raise ValueError(f"features must have shape (T, F), got {x.shape}")
    for name, value in (("frames", frames), ("stride", stride)):
        if not (isinstance(value, int) and value >= 1):
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    if len(x) < frames:
        return np.zeros((0, 2 * x.shape[1]))
    windows = np.lib.stride_tricks.sliding_window_view(x, frames, axis=0)[::stride]
    return np.concatenate([windows.mean(axis=-1), windows.std(axis=-1)], axis=1)


def window_features(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    other_root: np.ndarray,
    *,
    prefix: str = "",
    fps: float,
    window_s: float = WINDOW_S,
    stride_s: float | None = None,
    cutoff_hz: float = VELOCITY_CUTOFF_HZ,
) -> np.ndarray:
    """(W, D) window vectors (`WINDOW_FEATURES`) of one unbroken segment of a fighter's motion
    (`frame_features`' arguments); windows of ``window_s`` every ``stride_s`` (by default
    ``window_s``: no overlap). A segment shorter than a window gives none; one too short to
    filter (16 frames) too."""
    frames = round(window_s * fps)
    stride = frames if stride_s is None else round(stride_s * fps)
    if frames < 1 or stride < 1:
        raise ValueError(
            f"window_s and stride_s must span at least one frame at {fps} fps, got "
            f"{window_s} and {stride_s}"
        )
    q = np.asarray(qpos)
    if len(q) < max(frames, 16):
        return np.zeros((0, len(WINDOW_FEATURES)))
    features = frame_features(model, q, other_root, prefix=prefix, fps=fps, cutoff_hz=cutoff_hz)
    return summarise_windows(features, frames=frames, stride=stride)


def bout_windows(model: mujoco.MjModel, bouts: Bouts, agent: int) -> np.ndarray:
    """(W, D) window vectors of agent ``agent`` over every episode of ``bouts`` (run in arena
    ``model``), each episode a segment of its own."""
    index = humanoid_index(model, prefix=DEFAULT_PREFIXES[1 - agent])
    parts = [np.zeros((0, len(WINDOW_FEATURES)))]
    for episode in range(bouts.episodes):
        qpos = bouts.episode_qpos(episode)
        parts.append(
            window_features(
                model,
                qpos,
                qpos[:, index.qpos][:, ROOT_POS],
                prefix=DEFAULT_PREFIXES[agent],
                fps=bouts.policy_hz,
            )
        )
    return np.concatenate(parts)


def replay_windows(played: Played, fps: float) -> np.ndarray:
    """(W, D) window vectors of agent 0 in `play_clips`'s runs, each run up to the step its
    tracking ended (a fall or a drift ends it early)."""
    index = humanoid_index(played.model, prefix=DEFAULT_PREFIXES[1])
    parts = [np.zeros((0, len(WINDOW_FEATURES)))]
    for k, row in enumerate(r for r in played.rows if r.agent == 0):
        qpos = played.qpos[: row.frames, k]
        parts.append(
            window_features(
                played.model,
                qpos,
                qpos[:, index.qpos][:, ROOT_POS],
                prefix=DEFAULT_PREFIXES[0],
                fps=fps,
            )
        )
    return np.concatenate(parts)


def footage_windows(
    segments: Sequence[tuple[np.ndarray, np.ndarray, BoneLengths]], fps: float
) -> np.ndarray:
    """(W, D) window vectors of a fighter's footage: ``segments`` of (its qpos (T, 35), the
    other fighter's (T, 35), its bones), each unbroken, its humanoid compiled from its bones."""
    parts = [np.zeros((0, len(WINDOW_FEATURES)))]
    models: dict[BoneLengths, mujoco.MjModel] = {}
    for qpos, other, bones in segments:
        if bones not in models:
            models[bones] = mujoco.MjModel.from_xml_string(boxer_mjcf(bones))
        parts.append(window_features(models[bones], qpos, np.asarray(other)[:, ROOT_POS], fps=fps))
    return np.concatenate(parts)


# --------------------------------------------------------------------------
# The classifier test
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class TwoSampleResult:
    """A classifier test's outcome.

    Attributes:
        auc: the held-out scores' AUC, the chance that a real window scores above a simulated
            one (ties count half): 0.5 indistinguishable, 1 always told apart.
        low, high: its percentile bootstrap interval (`LEVEL`).
        n_real, n_fake: windows of each side.
    """

    auc: float
    low: float
    high: float
    n_real: int
    n_fake: int


def auc(real_scores: np.ndarray, fake_scores: np.ndarray) -> np.ndarray:
    """The AUC of scores (..., n_real) against (..., n_fake), batched over leading dimensions:
    the Mann-Whitney U of the real side over n_real n_fake, from the ranks of the pooled scores
    (ties share their mean rank, so count half)."""
    r = np.asarray(real_scores, dtype=np.float64)
    f = np.asarray(fake_scores, dtype=np.float64)
    n_real, n_fake = r.shape[-1], f.shape[-1]
    ranks = rankdata(np.concatenate([r, f], axis=-1), axis=-1)
    u = ranks[..., :n_real].sum(axis=-1) - n_real * (n_real + 1) / 2
    return u / (n_real * n_fake)


def _fit_logistic(
    x: np.ndarray, y: np.ndarray, weight: np.ndarray, l2: float
) -> tuple[np.ndarray, float]:
    """Weights and bias minimising sum_i weight_i logloss(y_i, x_i w + b) + l2 / 2 |w|^2."""
    dims = x.shape[1]

    def objective(theta: np.ndarray) -> tuple[float, np.ndarray]:
        w, b = theta[:dims], theta[dims]
        z = x @ w + b
        loss = weight @ (np.logaddexp(0.0, z) - y * z) + 0.5 * l2 * (w @ w)
        residual = weight * (0.5 * (1.0 + np.tanh(0.5 * z)) - y)  # d loss / d z, sigmoid - y
        return float(loss), np.concatenate([x.T @ residual + l2 * w, [residual.sum()]])

    theta = minimize(objective, np.zeros(dims + 1), jac=True, method="L-BFGS-B").x
    return theta[:dims], float(theta[dims])


def _folds(counts: tuple[int, int], folds: int, rng: np.random.Generator) -> np.ndarray:
    """Each window's fold, dealt in turn over a shuffle of each class (stratified)."""
    out = []
    for n in counts:
        fold = np.empty(n, dtype=np.int64)
        fold[rng.permutation(n)] = np.arange(n) % folds
        out.append(fold)
    return np.concatenate(out)


def held_out_scores(
    x: np.ndarray, y: np.ndarray, fold: np.ndarray, *, l2: float = L2
) -> np.ndarray:
    """(n,) every window's score (its logit of being real) from the logistic regression fitted,
    standardisation included, on the windows of the other folds; the classes weighted to equal
    totals."""
    scores = np.empty(len(y))
    for k in np.unique(fold):
        train, test = fold != k, fold == k
        mean = x[train].mean(axis=0)
        std = x[train].std(axis=0)
        std[std < 1e-12] = 1.0  # a feature constant over the training part carries nothing
        yt = y[train]
        weight = np.where(yt == 1, 0.5 / yt.sum(), 0.5 / (1 - yt).sum()) * len(yt)
        w, b = _fit_logistic((x[train] - mean) / std, yt, weight, l2)
        scores[test] = (x[test] - mean) / std @ w + b
    return scores


def classifier_test(
    real_windows: np.ndarray,
    fake_windows: np.ndarray,
    *,
    seed: int,
    folds: int = FOLDS,
    bootstrap: int = BOOTSTRAP,
    l2: float = L2,
) -> TwoSampleResult:
    """The held-out classifier test of real windows (n_real, D) against simulated ones
    (n_fake, D) (module docstring): folds and bootstrap drawn from ``seed``, so a seed gives the
    same result.

    Raises:
        ValueError: a side with fewer than ``folds`` windows (every fold must hold out at least
            one window of each side, and so every training part hold both), or windows that are
            not finite vectors of one width.
    """
    r = np.asarray(real_windows, dtype=np.float64)
    f = np.asarray(fake_windows, dtype=np.float64)
    if r.ndim != 2 or f.ndim != 2 or r.shape[1] != f.shape[1]:
        raise ValueError(
            f"real_windows and fake_windows must have shapes (n, D) with one D, got {r.shape} "
            f"and {f.shape}"
        )
    if not (np.isfinite(r).all() and np.isfinite(f).all()):
        raise ValueError("real_windows and fake_windows must be finite")
    for name, value, least in (("folds", folds, 2), ("bootstrap", bootstrap, 1)):
        if not (isinstance(value, int) and value >= least):
            raise ValueError(f"{name} must be an integer >= {least}, got {value!r}")
    if not (math.isfinite(l2) and l2 > 0):
        raise ValueError(f"l2 must be a positive number, got {l2!r}")
    for name, windows in (("real_windows", r), ("fake_windows", f)):
        if len(windows) < folds:
            raise ValueError(
                f"{name} has {len(windows)} windows; the test needs at least folds = {folds} "
                "of each side, one held out per fold"
            )
    rng = np.random.default_rng(seed)
    x = np.concatenate([r, f])
    y = np.r_[np.ones(len(r)), np.zeros(len(f))]
    scores = held_out_scores(x, y, _folds((len(r), len(f)), folds, rng), l2=l2)
    real, fake = scores[: len(r)], scores[len(r) :]
    resampled = auc(
        real[rng.integers(len(r), size=(bootstrap, len(r)))],
        fake[rng.integers(len(f), size=(bootstrap, len(f)))],
    )
    tail = 100 * (1 - LEVEL) / 2
    low, high = np.percentile(resampled, [tail, 100 - tail])
    return TwoSampleResult(float(auc(real, fake)), float(low), float(high), len(r), len(f))


def telltales(real: np.ndarray, simulated: np.ndarray, count: int = TELLTALES) -> str:
    """What gives ``simulated`` windows (W, D) away against ``real`` ones: the ``count``
    features whose means differ most, in pooled standard deviations (Cohen's d, real minus
    simulated), e.g. "left_ankle_y_mean +3.17, root_velocity_z_std -1.70". A feature constant on
    both sides differs by nothing."""
    pooled = np.sqrt(0.5 * (real.var(axis=0) + simulated.var(axis=0)))
    gap = real.mean(axis=0) - simulated.mean(axis=0)
    d = np.divide(gap, pooled, out=np.zeros_like(gap), where=pooled > 1e-12)
    order = np.argsort(-np.abs(d), kind="stable")[:count]
    return ", ".join(f"{WINDOW_FEATURES[i]} {d[i]:+.2f}" for i in order)


def feature_gap(reference: np.ndarray, simulated: np.ndarray) -> float:
    """How far ``simulated`` windows (W, D) are from ``reference`` windows (W', D): the mean over
    the D window features of |mean difference| / the reference's standard deviation, 0 when
    the means agree. The reference's spread is the yardstick for every fighter compared with it,
    so their figures share one scale. Features constant over the reference (no spread to measure
    by) are left out.

    Raises:
        ValueError: windows that are not finite (n, D) arrays of one D, an empty side, or a
            reference constant in every feature.
    """
    r = np.asarray(reference, dtype=np.float64)
    f = np.asarray(simulated, dtype=np.float64)
    if r.ndim != 2 or f.ndim != 2 or r.shape[1] != f.shape[1] or not (len(r) and len(f)):
        raise ValueError(
            f"reference and simulated must be non-empty (n, D) windows of one D, got {r.shape} "
            f"and {f.shape}"
        )
    if not (np.isfinite(r).all() and np.isfinite(f).all()):
        raise ValueError("reference and simulated must be finite")
    spread = r.std(axis=0)
    kept = spread > 1e-12
    if not kept.any():
        raise ValueError("reference windows are constant in every feature: nothing to scale by")
    gap = np.abs(r.mean(axis=0) - f.mean(axis=0))[kept] / spread[kept]
    return float(gap.mean())


def gap_closed(figure: float | None, still: float | None, replay: float | None) -> float | None:
    """The share of the gap between the still guard and the replay that a policy closes, on a
    figure where lower is closer (an AUC, a `feature_gap`): (still - figure) / (still -
    replay); 0 scores as the still guard, 1 as the tracker replaying the footage (the best a
    physics body can do), below 0 worse than standing still, above 1 better than the replay.
    None when a figure is missing or the still guard is not further off than the replay (the
    gap is not positive)."""
    if figure is None or still is None or replay is None:
        return None
    gap = still - replay
    if not gap > 0:
        return None
    return (still - figure) / gap
