"""Smoothers of one fighter's 2D keypoint tracks over time (one-euro, Savitzky-Golay, a
confidence-weighted local polynomial, an adaptive window).

Pure NumPy functions over a window of frames; inputs are never modified. Shapes as in
`tasks.pose.refine`: ``keypoints`` (T, J, 2) pixels, NaN where not observed; ``confidence``
(T, J) in [0, 1]; P polynomial coefficients.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.signal import savgol_coeffs

from tasks.pose.checks import check_positive, check_window, checked

# Weight floor for a finite point whose confidence is 0, so a window holding only such points
# still has a solvable fit (it then acts as an unweighted fit).
MIN_WEIGHT = 1e-3


# ---------------------------------------------------------------------------------------------
# Smoothers


def one_euro(
    keypoints: np.ndarray, fps: float, *, min_cutoff: float, beta: float, d_cutoff: float = 1.0
) -> np.ndarray:
    """The 1€ filter (Casiez, Roussel, Vogel, CHI 2012), causal, applied to every joint.

    Per frame: the speed estimate dx̂ is the previous one low-passed towards
    (x - x̂_prev) * fps at cutoff ``d_cutoff``; the position cutoff is
    f_c = ``min_cutoff`` + ``beta`` * |dx̂|; x̂ = x̂_prev + α (x - x̂_prev) with
    α = 1 / (1 + τ fps), τ = 1 / (2π f_c). Unlike the paper's 1-D form, |dx̂| is the joint's 2D
    speed, so x and y of one joint share a cutoff and a diagonal move is filtered like a straight
    one. A NaN frame ends a joint's filter; it restarts from the next observed point, so nothing is
    carried across a gap.

    Args:
        keypoints: (T, J, 2) pixels, NaN where missing.
        fps: frame rate (Hz).
        min_cutoff: cutoff at rest (Hz); lower = smoother when still.
        beta: cutoff gain per unit speed (Hz per px/s); higher = less lag when fast.
        d_cutoff: cutoff (Hz) of the speed estimate.

    Returns:
        (T, J, 2) filtered keypoints, NaN exactly where the input is.
    """
    kp, _ = checked(keypoints)
    check_positive("fps", fps)
    check_positive("min_cutoff", min_cutoff)
    check_positive("d_cutoff", d_cutoff)
    if beta < 0:
        raise ValueError(f"beta must be >= 0, got {beta}")

    def alpha(cutoff: np.ndarray | float) -> np.ndarray | float:
        tau = 1.0 / (2.0 * math.pi * cutoff)
        return 1.0 / (1.0 + tau * fps)

    num_joints = kp.shape[1]
    out = np.full_like(kp, np.nan)
    x_hat = np.zeros((num_joints, 2))
    dx_hat = np.zeros((num_joints, 2))
    running = np.zeros(num_joints, dtype=bool)
    alpha_d = alpha(d_cutoff)
    for t in range(kp.shape[0]):
        x = kp[t]
        seen = np.isfinite(x).all(axis=1)
        go = seen & running
        dx = np.where(go[:, None], (x - x_hat) * fps, 0.0)
        dx_hat = np.where(go[:, None], dx_hat + alpha_d * (dx - dx_hat), 0.0)
        a = alpha(min_cutoff + beta * np.linalg.norm(dx_hat, axis=1))[:, None]
        x_hat = np.where(go[:, None], x_hat + a * (x - x_hat), np.where(seen[:, None], x, 0.0))
        running = seen
        out[t, seen] = x_hat[seen]
    return out


def polynomial_weights(nodes: np.ndarray, at: np.ndarray, order: int) -> np.ndarray:
    """(len(at), len(nodes)) weights W such that W @ y is the least-squares polynomial of degree
    ``order`` through (nodes, y), evaluated at ``at``.

    With V the (N, P) Vandermonde matrix of ``nodes`` the fit is a = (VᵀV)⁻¹Vᵀ y, so
    W = V_at (VᵀV)⁻¹Vᵀ; nodes are centred on their mean first to keep VᵀV well conditioned.
    Ours rather than scipy's `savgol_coeffs` because the nodes may be any frames (a run shorter
    than the window, the local fits of `confidence_weighted` and `adaptive_window`), where
    `savgol_coeffs` takes an evenly spaced window only.
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    at = np.asarray(at, dtype=np.float64)
    centre = nodes.mean()
    vander = np.vander(nodes - centre, order + 1, increasing=True)
    fit = np.linalg.solve(vander.T @ vander, vander.T)  # (P, N)
    return np.vander(at - centre, order + 1, increasing=True) @ fit


def savgol_coefficients(window: int, order: int) -> np.ndarray:
    """(window,) Savitzky-Golay smoothing weights for the centre of a window (Savitzky & Golay,
    Anal. Chem. 1964): the least-squares polynomial of degree ``order`` evaluated at the centre.

    window 5, order 2 gives [-3, 12, 17, 12, -3] / 35. scipy's `savgol_coeffs`.
    """
    check_window("window", window, order, order_name="order")
    return savgol_coeffs(window, order, use="dot")


def _finite_runs(valid: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of each run of True in the 1-D bool array ``valid``."""
    edges = np.diff(np.concatenate([[0], valid.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


def savitzky_golay(keypoints: np.ndarray, *, window: int, order: int) -> np.ndarray:
    """Savitzky-Golay smoothing of every joint, within each run of observed frames.

    Interior frames get :func:`savgol_coefficients`; the first and last ``window // 2`` frames of
    a run get the same window's polynomial evaluated off-centre (no padding, so no made-up
    data). A run shorter than ``window`` is fitted whole with degree min(order, length - 1).
    Runs are split at every NaN, so nothing is smoothed across a gap.

    Args:
        keypoints: (T, J, 2) pixels, NaN where missing.
        window: odd window length in frames.
        order: polynomial degree, < window.

    Returns:
        (T, J, 2) smoothed keypoints, NaN exactly where the input is.
    """
    kp, _ = checked(keypoints)
    check_window("window", window, order, order_name="order")
    half = window // 2
    centre = savgol_coefficients(window, order)
    # The same window's polynomial at its first and last `half` frames (empty when half is 0).
    edge = [savgol_coeffs(window, order, pos=p, use="dot") for p in range(window)]
    head = np.reshape(edge[:half], (half, window))
    tail = np.reshape(edge[window - half :], (half, window))
    out = np.full_like(kp, np.nan)
    observed = np.isfinite(kp).all(axis=2)
    for j in range(kp.shape[1]):
        for start, end in _finite_runs(observed[:, j]):
            y = kp[start:end, j]  # (n, 2)
            n = end - start
            if n < window:
                steps = np.arange(n)
                out[start:end, j] = polynomial_weights(steps, steps, min(order, n - 1)) @ y
                continue
            windows = np.lib.stride_tricks.sliding_window_view(y, window, axis=0)  # (n-w+1,2,w)
            out[start + half : end - half, j] = windows @ centre
            out[start : start + half, j] = head @ y[:window]
            out[end - half : end, j] = tail @ y[n - window :]
    return out


def confidence_weighted(
    keypoints: np.ndarray,
    confidence: np.ndarray,
    *,
    window: int,
    order: int = 2,
    robust_iterations: int = 1,
) -> np.ndarray:
    """Confidence-weighted local polynomial regression (LOESS, Cleveland 1979) of every joint.

    Each frame t is replaced by the value at t of the degree-``order`` polynomial fitted by
    weighted least squares to the frames t-h..t+h (h = window // 2) of its run of observed frames,
    with weights tricube(u / (h + 1)) * confidence * robustness. The window is centred, so a fast
    punch is not lagged (unlike a causal filter), and a quadratic follows its turn-around. After
    the first fit, ``robust_iterations`` rounds of Cleveland's robustness weights (Tukey's
    biweight of the residual over 6 × the joint's median residual) cut outliers down. Near a
    run's ends the window is one-sided; where a run has too few frames the degree drops to
    (points - 1). Runs are split at every NaN, so nothing is smoothed across a gap.

    Args:
        keypoints: (T, J, 2) pixels, NaN where missing.
        confidence: (T, J) in [0, 1], the fit weights (floored at a small positive value).
        window: odd window length in frames, at least 2 * order + 1 so that the one-sided window
            at a run's end still holds order + 1 points.
        order: polynomial degree.
        robust_iterations: rounds of outlier reweighting; 0 for a plain weighted fit.

    Returns:
        (T, J, 2) smoothed keypoints, NaN exactly where the input is.
    """
    kp, conf = checked(keypoints, confidence)
    check_window("window", window, order, order_name="order")
    if window < 2 * order + 1:
        raise ValueError(f"window must be at least 2 * order + 1 = {2 * order + 1}, got {window}")
    if robust_iterations < 0:
        raise ValueError(f"robust_iterations must be >= 0, got {robust_iterations}")
    observed = np.isfinite(kp).all(axis=2)
    weight = np.where(observed, np.maximum(conf, MIN_WEIGHT), 0.0)
    fit, _ = _local_fit(kp, observed, weight, window // 2, order)
    for _ in range(robust_iterations):
        robust = weight * _biweight(np.linalg.norm(kp - fit, axis=2), observed)
        fit, _ = _local_fit(kp, observed, robust, window // 2, order)
    return fit


def _per_joint_median(values: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """(J,) median over the observed frames of each joint of the (T, J) ``values``; NaN if none."""
    out = np.full(values.shape[1], np.nan)
    for j in np.flatnonzero(observed.any(axis=0)):
        out[j] = np.median(values[observed[:, j], j])
    return out


def _biweight(residual: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """(T, J) Cleveland's robustness weights: Tukey's biweight of each point's residual over six
    times its joint's median residual, floored so no observed point drops out entirely."""
    scale = 6.0 * _per_joint_median(residual, observed)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(scale > 0, residual / scale, 0.0)
    return np.maximum(np.where(ratio < 1.0, (1.0 - ratio**2) ** 2, 0.0), MIN_WEIGHT)


def noise_px(keypoints: np.ndarray) -> np.ndarray:
    """(J,) robust estimate of each joint's per-coordinate noise σ (px), NaN if unmeasurable.

    For white noise of variance σ² on a slowly varying path, each coordinate's second difference
    x[t+1] - 2 x[t] + x[t-1] has variance 6 σ²; its median absolute value is 0.6745 √6 σ. The
    median ignores the few frames where real acceleration (a punch) dominates.
    """
    kp, _ = checked(keypoints)
    second = kp[2:] - 2.0 * kp[1:-1] + kp[:-2]  # (T-2, J, 2)
    observed = np.isfinite(second).all(axis=2)
    size = np.abs(second).reshape(len(second), 2 * kp.shape[1])
    both = np.repeat(observed, 2, axis=1)
    per_coord = _per_joint_median(size, both).reshape(-1, 2)
    return per_coord.mean(axis=1) / (0.6745 * math.sqrt(6.0))


def adaptive_window(
    keypoints: np.ndarray,
    confidence: np.ndarray,
    *,
    windows: Sequence[int] = (5, 9, 13, 17),
    order: int = 2,
    threshold: float = 1.0,
    robust_iterations: int = 1,
) -> np.ndarray:
    """Local polynomial regression whose window each point picks by the intersection of
    confidence intervals rule (ICI: Goldenshluger & Nemirovski 1997; Katkovnik 1999).

    For every joint-frame, the confidence-weighted fits of :func:`confidence_weighted` over each
    of ``windows`` (shortest first) give estimates x̂_h with standard deviation σ_j √v_h (σ_j the
    joint's noise from :func:`noise_px`, v_h the fit's variance factor). The longest window whose
    interval x̂_h ± ``threshold`` σ_j √v_h still meets every shorter window's (in x and y) is kept:
    a still joint gets the longest window and little jitter, a punching wrist, where the long
    fits' bias pulls them off the short ones, a short window and no lag or peak clipping.
    Each of ``robust_iterations`` rounds then reweights every point by Cleveland's biweight of
    its residual from the previous choice (see :func:`confidence_weighted`) and chooses again;
    residuals from the chosen fit, not the longest, so a punch's peak is not taken for an
    outlier. σ_j is measured, not given, so the rule adapts to each video's noise.

    Args:
        keypoints: (T, J, 2) pixels, NaN where missing.
        confidence: (T, J) in [0, 1], the fit weights (floored at a small positive value).
        windows: odd window lengths in frames, increasing, each at least 2 * order + 1.
        order: polynomial degree.
        threshold: interval half-width in standard deviations; larger = longer windows.
        robust_iterations: rounds of outlier reweighting; 0 for none.

    Returns:
        (T, J, 2) smoothed keypoints, NaN exactly where the input is.
    """
    kp, conf = checked(keypoints, confidence)
    windows = tuple(windows)
    if not windows or list(windows) != sorted(set(windows)):
        raise ValueError(f"windows must be increasing window lengths, got {windows}")
    for window in windows:
        check_window("windows", window, order, order_name="order")
        if window < 2 * order + 1:
            raise ValueError(f"windows must each be at least 2 * order + 1, got {window}")
    check_positive("threshold", threshold)
    if robust_iterations < 0:
        raise ValueError(f"robust_iterations must be >= 0, got {robust_iterations}")
    observed = np.isfinite(kp).all(axis=2)
    weight = np.where(observed, np.maximum(conf, MIN_WEIGHT), 0.0)
    sigma = noise_px(kp)
    known = np.isfinite(sigma)
    sigma = np.where(known, sigma, np.median(sigma[known]) if known.any() else 0.0)
    fit = _ici_fit(kp, observed, weight, sigma, windows, order, threshold)
    for _ in range(robust_iterations):
        robust = weight * _biweight(np.linalg.norm(kp - fit, axis=2), observed)
        fit = _ici_fit(kp, observed, robust, sigma, windows, order, threshold)
    return fit


def _ici_fit(
    kp: np.ndarray,
    observed: np.ndarray,
    weight: np.ndarray,
    sigma: np.ndarray,
    windows: tuple[int, ...],
    order: int,
    threshold: float,
) -> np.ndarray:
    """(T, J, 2) the ICI choice among the local fits over ``windows`` (see adaptive_window)."""
    lower = np.full(kp.shape, -np.inf)
    upper = np.full(kp.shape, np.inf)
    chosen = np.full_like(kp, np.nan)
    agree = observed.copy()  # points whose intervals have all met so far
    for window in windows:
        fit, variance = _local_fit(kp, observed, weight, window // 2, order)
        half_width = (threshold * sigma[None, :] * np.sqrt(variance))[..., None]
        lower = np.maximum(lower, fit - half_width)
        upper = np.minimum(upper, fit + half_width)
        agree &= (lower <= upper).all(axis=2)
        chosen[agree] = fit[agree]
    return chosen


def _local_fit(
    kp: np.ndarray, observed: np.ndarray, weight: np.ndarray, half: int, order: int
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted local polynomial value at each frame (see confidence_weighted) and its variance
    per unit noise variance, vectorised over frames and joints.

    The fit at t is e0ᵀ M⁻¹ Σ w_u x_u [1, u, .., u^P] with M = Σ w_u [u^(i+k)]; for independent
    noise of variance σ² its variance is σ² zᵀ (Σ w_u² [u^(i+k)]) z with z = M⁻¹ e0. The sums are
    built one window offset u at a time.

    Returns (T, J, 2) fit and (T, J) variance factor, NaN where unobserved.
    """
    num_frames = kp.shape[0]
    # Run label per joint-frame: it steps at every unobserved frame, so two frames share a label
    # only if no gap lies between them.
    run = np.cumsum(~observed, axis=0)
    pad = ((half, half), (0, 0))
    kp_p = np.pad(np.nan_to_num(kp), pad + ((0, 0),))
    w_p = np.pad(weight, pad)
    run_p = np.pad(run, pad, constant_values=-1)
    obs_p = np.pad(observed, pad)
    moments = np.zeros((2 * order + 1, *weight.shape))  # sum of w u^m
    moments_sq = np.zeros_like(moments)  # sum of w² u^m
    targets = np.zeros((order + 1, *kp.shape))  # sum of w u^m x
    count = np.zeros(weight.shape, dtype=int)
    for u in range(-half, half + 1):
        rows = slice(half + u, half + u + num_frames)
        same = obs_p[rows] & (run_p[rows] == run) & observed
        kernel = (1.0 - (abs(u) / (half + 1.0)) ** 3) ** 3
        w = np.where(same, kernel * w_p[rows], 0.0)
        powers = (float(u) ** np.arange(2 * order + 1))[:, None, None]
        moments += powers * w
        moments_sq += powers * w**2
        targets += powers[: order + 1, ..., None] * (w[..., None] * kp_p[rows])
        count += same
    fit = np.full_like(kp, np.nan)
    variance = np.full(weight.shape, np.nan)
    # Highest degree each point's window supports; lower degrees fill in where fewer points exist.
    degree = np.minimum(order, count - 1)
    for q in range(order + 1):
        pick = observed & (degree == q)
        if not pick.any():
            continue
        index = np.arange(q + 1)
        hankel = index[:, None] + index[None, :]
        normal = moments[hankel][:, :, pick].transpose(2, 0, 1)  # (n, P, P)
        normal_sq = moments_sq[hankel][:, :, pick].transpose(2, 0, 1)
        rhs = targets[: q + 1][:, pick].transpose(1, 0, 2)  # (n, P, 2)
        fit[pick] = np.linalg.solve(normal, rhs)[:, 0, :]
        z = np.linalg.solve(normal, np.broadcast_to(np.eye(q + 1)[:, :1], (len(normal), q + 1, 1)))
        variance[pick] = (z.transpose(0, 2, 1) @ normal_sq @ z)[:, 0, 0]
    return fit, variance
