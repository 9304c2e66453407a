"""Temporal refinement of one fighter's 2D keypoints: undo left/right flips, fill gaps, smooth.

Everything here is a pure NumPy function over a window of frames; inputs are never modified.

Shape letters: T frames, J joints (33 for BlazePose), P polynomial coefficients.
Layout: ``keypoints`` (T, J, 2) float image pixels (x right, y down), NaN where the joint was not
observed; ``confidence`` (T, J) in [0, 1], 0 where missing.

Order of work in :func:`refine`: flips first (a swapped frame would otherwise be interpolated
and smoothed into its neighbours), then gaps (so the smoothers see short gaps bridged), then one
smoother picked by name from :data:`SMOOTHERS`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from models.settings import setting

# BlazePose joint names without their left/right word, by the limb that BlazePose tends to
# mislabel as a unit. Each group decides alone, so a swap of the legs alone is seen (one
# whole-body vote would be split between correct arms and swapped legs). Shoulders and hips form
# their own group so that a swap of the knees-down chain does not drag correct hips along.
FLIP_GROUPS: Mapping[str, tuple[str, ...]] = {
    "face": ("eye_inner", "eye", "eye_outer", "ear", "mouth"),
    "torso": ("shoulder", "hip"),
    "arms": ("elbow", "wrist", "pinky", "index", "thumb"),
    "legs": ("knee", "ankle", "heel", "foot_index"),
}

# Upper arms and thighs (base names, parent first): a swap of the group holding the child may not
# make the two bones cross where the model's labels left them apart (see fix_flips).
FLIP_BONES: tuple[tuple[str, str], ...] = (("shoulder", "elbow"), ("hip", "knee"))

_SIDES = {"left": "right", "right": "left"}

# Weight floor for a finite point whose confidence is 0, so a window holding only such points
# still has a solvable fit (it then acts as an unweighted fit).
_MIN_WEIGHT = 1e-3


# ---------------------------------------------------------------------------------------------
# Checks


def _checked(
    keypoints: np.ndarray, confidence: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """float64 copies of the inputs after shape and value checks that name the argument."""
    kp = np.array(keypoints, dtype=np.float64, copy=True)
    if kp.ndim != 3 or kp.shape[2] != 2:
        raise ValueError(f"keypoints must have shape (T, J, 2), got {kp.shape}")
    if np.isinf(kp).any():
        raise ValueError("keypoints must be finite or NaN, got inf")
    if confidence is None:
        return kp, None
    conf = np.array(confidence, dtype=np.float64, copy=True)
    if conf.shape != kp.shape[:2]:
        raise ValueError(
            f"confidence must have shape (T, J) = {kp.shape[:2]} to match keypoints, "
            f"got {conf.shape}"
        )
    if not np.isfinite(conf).all() or (conf < 0).any() or (conf > 1).any():
        raise ValueError("confidence must hold values in [0, 1] (use 0 for missing joints)")
    return kp, conf


def _check_positive(name: str, value: float) -> None:
    if not value > 0:
        raise ValueError(f"{name} must be > 0, got {value}")


def _check_window(name: str, window: int, order: int, *, order_name: str) -> None:
    if order < 0:
        raise ValueError(f"{order_name} must be >= 0, got {order}")
    if window < 1 or window % 2 == 0:
        raise ValueError(f"{name} must be a positive odd number of frames, got {window}")
    if window <= order:
        raise ValueError(f"{name} ({window}) must be larger than {order_name} ({order})")


def _check_perm(perm: np.ndarray, num_joints: int) -> np.ndarray:
    perm = np.asarray(perm)
    if perm.shape != (num_joints,) or not np.issubdtype(perm.dtype, np.integer):
        raise ValueError(f"perm must be an int array of shape ({num_joints},), got {perm.shape}")
    if not np.array_equal(np.sort(perm), np.arange(num_joints)):
        raise ValueError("perm must be a permutation of 0..J-1")
    if not np.array_equal(perm[perm], np.arange(num_joints)):
        raise ValueError("perm must be its own inverse (each joint's mirror mirrors back)")
    return perm


def _check_groups(groups: Sequence[np.ndarray] | None, perm: np.ndarray) -> list[np.ndarray]:
    if groups is None:
        paired = np.flatnonzero(perm != np.arange(len(perm)))
        return [paired] if len(paired) else []
    seen = np.zeros(len(perm), dtype=bool)
    checked = []
    for g, joints in enumerate(groups):
        joints = np.asarray(joints, dtype=np.intp)
        if joints.ndim != 1 or (joints < 0).any() or (joints >= len(perm)).any():
            raise ValueError(f"groups[{g}] must be a 1-D array of joint indices < {len(perm)}")
        if set(perm[joints].tolist()) != set(joints.tolist()):
            raise ValueError(f"groups[{g}] must hold each of its joints' mirrors too")
        if seen[joints].any():
            raise ValueError(f"groups[{g}] overlaps an earlier group")
        seen[joints] = True
        checked.append(joints)
    return checked


# ---------------------------------------------------------------------------------------------
# Left/right flips


def flip_permutation(names: Sequence[str]) -> np.ndarray:
    """(J,) int index of each joint's left/right mirror; midline joints map to themselves.

    A name is mirrored by swapping the word ``left`` for ``right`` (and back) among its
    ``_``-separated parts, so ``left_knee`` pairs with ``right_knee`` and BlazePose's
    ``mouth_left`` with ``mouth_right``. Raises ValueError naming ``names`` when a sided joint has
    no mirror or a name repeats.
    """
    index = {name: i for i, name in enumerate(names)}
    if len(index) != len(names):
        raise ValueError("names must not repeat a joint name")
    perm = np.arange(len(names))
    for i, name in enumerate(names):
        mirrored = "_".join(_SIDES.get(part, part) for part in name.split("_"))
        if mirrored != name:
            if mirrored not in index:
                raise ValueError(f"names: {name!r} has no mirror {mirrored!r}")
            perm[i] = index[mirrored]
    return perm


def _base_name(name: str) -> str:
    return "_".join(part for part in name.split("_") if part not in _SIDES)


def flip_groups(names: Sequence[str]) -> tuple[np.ndarray, ...]:
    """Joint indices of each limb group in :data:`FLIP_GROUPS` present in ``names``.

    Each group holds the sided joints whose name without its left/right word is listed for it,
    together with their mirrors; sided joints not listed anywhere form one last group. Midline
    joints (nose) are in no group. Pass the result to :func:`fix_flips` as ``groups``.
    """
    perm = flip_permutation(names)
    sided = perm != np.arange(len(names))
    bases = [_base_name(name) for name in names]
    groups, used = [], np.zeros(len(names), dtype=bool)
    for parts in FLIP_GROUPS.values():
        member = sided & np.isin(bases, parts)
        if member.any():
            groups.append(np.flatnonzero(member))
            used |= member
    rest = sided & ~used
    if rest.any():
        groups.append(np.flatnonzero(rest))
    return tuple(groups)


def flip_bones(names: Sequence[str]) -> tuple[tuple[int, int], ...]:
    """(parent, child) indices of the left side's bones of :data:`FLIP_BONES` in ``names``, for
    :func:`fix_flips`'s ``bones``."""
    index = {name: i for i, name in enumerate(names)}
    return tuple(
        (index[f"left_{parent}"], index[f"left_{child}"])
        for parent, child in FLIP_BONES
        if f"left_{parent}" in index and f"left_{child}" in index
    )


def _crossed(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """(T,) whether 2D segments a0-a1 and b0-b1 (each (T, 2)) cross; False where any is NaN."""

    def side(p, q, r):
        return np.sign(
            (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])
        )

    with np.errstate(invalid="ignore"):
        return (side(a0, a1, b0) * side(a0, a1, b1) < 0) & (side(b0, b1, a0) * side(b0, b1, a1) < 0)


def _invents_cross(
    kp: np.ndarray, parents: np.ndarray, perm: np.ndarray, joints: np.ndarray, bones
) -> np.ndarray:
    """(T,) frames where swapping ``joints``' labels would make a bone of ``bones`` cross its
    mirror while the labels as given leave them apart. ``parents`` (T, J, 2) holds the parent
    joints as already decided (their own group may have been swapped)."""
    vetoed = np.zeros(len(kp), dtype=bool)
    for parent, child in bones:
        if child not in joints or parent in joints:
            continue
        left, right = parents[:, parent], parents[:, perm[parent]]
        as_is = _crossed(left, kp[:, child], right, kp[:, perm[child]])
        swapped = _crossed(left, kp[:, perm[child]], right, kp[:, child])
        vetoed |= swapped & ~as_is
    return vetoed


def _group_swaps(
    kp: np.ndarray,
    conf: np.ndarray,
    perm: np.ndarray,
    joints: np.ndarray,
    *,
    min_confidence: float,
    ratio: float,
    max_age: int,
    vetoed: np.ndarray,
) -> np.ndarray:
    """(T,) bool frames where ``joints``' left/right labels are to be swapped (see fix_flips);
    never a frame of ``vetoed``."""
    num_frames = kp.shape[0]
    mirror = perm[joints]
    ref = np.full((len(joints), 2), np.nan)  # last accepted position of each label in the group
    ref_frame = np.full(len(joints), -(10**9))
    # Position of each joint's mirror inside `joints`, to read the mirror's reference.
    where = {int(j): k for k, j in enumerate(joints)}
    mirror_k = np.array([where[int(m)] for m in mirror])
    swap = np.zeros(num_frames, dtype=bool)
    segment = np.full(num_frames, -1)  # reference chain each frame belongs to; -1 = not seen
    current = -1
    for t in range(num_frames):
        cur = kp[t, joints]
        weight = conf[t, joints]
        valid = np.isfinite(cur).all(axis=1) & (weight >= min_confidence)
        if not valid.any():
            continue
        fresh = t - ref_frame <= max_age
        use = valid & fresh & fresh[mirror_k]
        if use.any():
            w = np.maximum(weight[use], _MIN_WEIGHT)
            as_is = np.sum(w * np.linalg.norm(cur[use] - ref[use], axis=1))
            mirrored = np.sum(w * np.linalg.norm(cur[use] - ref[mirror_k[use]], axis=1))
            swap[t] = mirrored < ratio * as_is and not vetoed[t]
        else:
            current += 1  # no usable reference: a new chain starts, its parity unknown
        segment[t] = current
        # The label a point carries after the decision: a swap moves joint j's point to mirror(j).
        label = mirror_k if swap[t] else np.arange(len(joints))
        ref[label[valid]] = cur[valid]
        ref_frame[label[valid]] = t
    # A chain's parity is set by its first frame, which may itself be flipped; flips are the
    # exception, so a chain where most frames were swapped started flipped and is inverted.
    for s in range(current + 1):
        in_segment = segment == s
        inverted = in_segment & ~swap
        # An inversion that would cross bones the model left apart is not the better reading.
        if 2 * swap[in_segment].sum() > in_segment.sum() and not (inverted & vetoed).any():
            swap[in_segment] = ~swap[in_segment]
    return swap


def fix_flips(
    keypoints: np.ndarray,
    confidence: np.ndarray,
    perm: np.ndarray,
    *,
    groups: Sequence[np.ndarray] | None = None,
    bones: Sequence[tuple[int, int]] = (),
    min_confidence: float = 0.3,
    ratio: float = 0.5,
    max_age: int = 10,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Swap back the limb groups whose left/right labels flipped relative to their neighbours.

    Decided per limb group (``groups``, e.g. :func:`flip_groups`; default: all sided joints as one
    whole-body group), frame by frame in time order. A group's cost against its reference (the
    last accepted position of each label, at most ``max_age`` frames old) is the
    confidence-weighted sum of point distances, as-is and with every joint read as its mirror
    ``perm[j]``; the frame's group is swapped when mirrored < ``ratio`` * as-is. A near tie (a
    fighter side-on, limbs overlapping) is left alone. BlazePose typically swaps the legs alone, or
    the whole body when the fighter turns; the first flips the legs group, the second every group.

    Each unbroken chain of references is then checked as a whole: if most of its frames were
    swapped, its first frame was the flipped one and the chain's decisions are inverted.

    A swap never makes a bone of ``bones`` (a thigh, an upper arm) cross its mirror where the
    labels as given leave the two apart, and a chain is not inverted when that would do so:
    legs really crossed for a while (a crossover step) read as a flip, the chain's majority
    was inverted, and the thighs of the frames around it came out crossed in an X.

    Args:
        keypoints: (T, J, 2) pixels, NaN where missing.
        confidence: (T, J) in [0, 1]; joints below ``min_confidence`` neither vote nor become a
            reference (they are still swapped with their group).
        perm: (J,) mirror of each joint, from :func:`flip_permutation`.
        groups: disjoint joint-index arrays, each closed under ``perm``; a group holding the
            parents of ``bones`` comes before the group of their children.
        bones: (parent, child) of left-side bones, e.g. :func:`flip_bones`.

    Returns:
        keypoints (T, J, 2) and confidence (T, J) with the swaps applied, and the number of frames
        in which at least one group was swapped.
    """
    kp, conf = _checked(keypoints, confidence)
    perm = _check_perm(perm, kp.shape[1])
    checked = _check_groups(groups, perm)
    _check_positive("ratio", ratio)
    if max_age < 1:
        raise ValueError(f"max_age must be >= 1 frame, got {max_age}")
    out_kp, out_conf = kp.copy(), conf.copy()
    any_swap = np.zeros(kp.shape[0], dtype=bool)
    for joints in checked:
        swap = _group_swaps(
            kp,
            conf,
            perm,
            joints,
            min_confidence=min_confidence,
            ratio=ratio,
            max_age=max_age,
            vetoed=_invents_cross(kp, out_kp, perm, joints, bones),
        )
        frames = np.flatnonzero(swap)
        out_kp[np.ix_(frames, joints)] = kp[np.ix_(frames, perm[joints])]
        out_conf[np.ix_(frames, joints)] = conf[np.ix_(frames, perm[joints])]
        any_swap |= swap
    return out_kp, out_conf, int(any_swap.sum())


# ---------------------------------------------------------------------------------------------
# Gaps


def fill_gaps(
    keypoints: np.ndarray, confidence: np.ndarray, *, max_gap: int, min_confidence: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Linearly interpolate each joint across runs of at most ``max_gap`` untrusted frames.

    A joint-frame is untrusted when it is NaN or its confidence is below ``min_confidence``.
    A run bounded by trusted frames on both sides and no longer than ``max_gap`` frames is
    filled on the straight line between them, with confidence min(anchors) * (1 - d / (L + 1))
    (d frames to the nearer anchor, L the run length), so a filled point always counts for less
    than its anchors and less the deeper it lies in the gap. Every other untrusted point,
    in longer runs or at the ends of the window, becomes NaN with confidence 0: one_euro and
    savitzky_golay do not weigh by confidence, so an untrusted point left in would pull its
    trusted neighbours.

    Args:
        keypoints: (T, J, 2) pixels, NaN where missing.
        confidence: (T, J) in [0, 1].
        max_gap: longest run (frames) to fill; 0 fills nothing.
        min_confidence: trust threshold in [0, 1].

    Returns:
        keypoints (T, J, 2), confidence (T, J), and filled (T, J) bool marking the filled points.
    """
    kp, conf = _checked(keypoints, confidence)
    if max_gap < 0:
        raise ValueError(f"max_gap must be >= 0 frames, got {max_gap}")
    if not 0.0 <= min_confidence <= 1.0:
        raise ValueError(f"min_confidence must be in [0, 1], got {min_confidence}")
    num_frames, num_joints = conf.shape
    trusted = np.isfinite(kp).all(axis=2) & (conf >= min_confidence)
    filled = np.zeros((num_frames, num_joints), dtype=bool)
    for j in range(num_joints):
        good = np.flatnonzero(trusted[:, j])
        bad = np.flatnonzero(~trusted[:, j])
        if len(bad) == 0:
            continue
        if len(good) == 0:
            kp[:, j], conf[:, j] = np.nan, 0.0
            continue
        after = np.searchsorted(good, bad)  # index in `good` of the next trusted frame
        inside = (after > 0) & (after < len(good))
        prev = good[np.clip(after - 1, 0, len(good) - 1)]
        nxt = good[np.clip(after, 0, len(good) - 1)]
        length = np.where(inside, nxt - prev - 1, max_gap + 1)
        fill = inside & (length <= max_gap)
        t, a, b, n = bad[fill], prev[fill], nxt[fill], length[fill]
        share = ((t - a) / (b - a))[:, None]
        kp[t, j] = kp[a, j] + share * (kp[b, j] - kp[a, j])
        depth = np.minimum(t - a, b - t)
        conf[t, j] = np.minimum(conf[a, j], conf[b, j]) * (1.0 - depth / (n + 1.0))
        filled[t, j] = True
        drop = bad[~fill]
        kp[drop, j] = np.nan
        conf[drop, j] = 0.0
    return kp, conf, filled


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
    kp, _ = _checked(keypoints)
    _check_positive("fps", fps)
    _check_positive("min_cutoff", min_cutoff)
    _check_positive("d_cutoff", d_cutoff)
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

    window 5, order 2 gives [-3, 12, 17, 12, -3] / 35.
    """
    _check_window("window", window, order, order_name="order")
    half = window // 2
    return polynomial_weights(np.arange(-half, half + 1), np.array([0.0]), order)[0]


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
    kp, _ = _checked(keypoints)
    _check_window("window", window, order, order_name="order")
    half = window // 2
    positions = np.arange(window)
    centre = savgol_coefficients(window, order)
    head = polynomial_weights(positions, positions[:half], order)
    tail = polynomial_weights(positions, positions[window - half :], order)
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
    kp, conf = _checked(keypoints, confidence)
    _check_window("window", window, order, order_name="order")
    if window < 2 * order + 1:
        raise ValueError(f"window must be at least 2 * order + 1 = {2 * order + 1}, got {window}")
    if robust_iterations < 0:
        raise ValueError(f"robust_iterations must be >= 0, got {robust_iterations}")
    observed = np.isfinite(kp).all(axis=2)
    weight = np.where(observed, np.maximum(conf, _MIN_WEIGHT), 0.0)
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
    return np.maximum(np.where(ratio < 1.0, (1.0 - ratio**2) ** 2, 0.0), _MIN_WEIGHT)


def noise_px(keypoints: np.ndarray) -> np.ndarray:
    """(J,) robust estimate of each joint's per-coordinate noise σ (px), NaN if unmeasurable.

    For white noise of variance σ² on a slowly varying path, each coordinate's second difference
    x[t+1] - 2 x[t] + x[t-1] has variance 6 σ²; its median absolute value is 0.6745 √6 σ. The
    median ignores the few frames where real acceleration (a punch) dominates.
    """
    kp, _ = _checked(keypoints)
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
    kp, conf = _checked(keypoints, confidence)
    windows = tuple(windows)
    if not windows or list(windows) != sorted(set(windows)):
        raise ValueError(f"windows must be increasing window lengths, got {windows}")
    for window in windows:
        _check_window("windows", window, order, order_name="order")
        if window < 2 * order + 1:
            raise ValueError(f"windows must each be at least 2 * order + 1, got {window}")
    _check_positive("threshold", threshold)
    if robust_iterations < 0:
        raise ValueError(f"robust_iterations must be >= 0, got {robust_iterations}")
    observed = np.isfinite(kp).all(axis=2)
    weight = np.where(observed, np.maximum(conf, _MIN_WEIGHT), 0.0)
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


# ---------------------------------------------------------------------------------------------
# Metric


def jitter_px(keypoints: np.ndarray) -> float:
    """Mean magnitude of the 2D second difference x[t+1] - 2 x[t] + x[t-1] (px / frame²).

    Taken over every joint and frame t whose three frames are all observed; NaN if there is none.
    This is the pose stage's ``jitter_px`` metric. Real motion has some (a punch's turn-around),
    so lower is better only down to the truth's own value.

    Args:
        keypoints: (T, J, 2) pixels, NaN where missing.
    """
    kp, _ = _checked(keypoints)
    if kp.shape[0] < 3:
        return float("nan")
    second = kp[2:] - 2.0 * kp[1:-1] + kp[:-2]
    size = np.linalg.norm(second, axis=2)
    size = size[np.isfinite(size)]
    return float(size.mean()) if size.size else float("nan")


# ---------------------------------------------------------------------------------------------
# Configured stage step


@dataclass(frozen=True)
class RefineConfig:
    """How one fighter's 2D keypoints are refined over a chunk of frames.

    Smoother parameters are the picks of ``benchmarks/refine_filters.py --sweep`` on the
    synthetic fighter (about 400 px tall, 30 fps); pixel- and frame-based ones want revisiting
    for much smaller fighters or other frame rates.
    """

    smoother: str = setting(
        "adaptive_window",
        "Smoother applied last, a name in SMOOTHERS: none, one_euro, savitzky_golay, "
        "confidence_weighted, adaptive_window (the winner of benchmarks/refine_filters.py).",
    )
    min_confidence: float = setting(
        0.3,
        "Joint confidence (0-1) below which a point is untrusted: it neither votes on flips nor "
        "survives gap filling (replaced when the gap is short, else NaN).",
    )
    max_gap: int = setting(
        5, "Longest run of missing or untrusted frames (per joint) that is interpolated."
    )
    flip_ratio: float = setting(
        0.5,
        "A limb group's left/right labels are swapped back when its mirrored cost against the "
        "previous frames is below this share of its as-is cost.",
    )
    flip_max_age: int = setting(
        10, "Frames after which a joint's last position no longer serves as a flip reference."
    )
    one_euro_min_cutoff: float = setting(2.0, "1€ filter cutoff at rest (Hz).")
    one_euro_beta: float = setting(
        0.1,
        "1€ filter cutoff gain per unit speed (Hz per px/s); in pixels, so it suits fighters "
        "about 400 px tall and wants scaling with their size.",
    )
    one_euro_d_cutoff: float = setting(5.0, "1€ filter cutoff of its speed estimate (Hz).")
    sg_window: int = setting(7, "Savitzky-Golay window (odd, frames).")
    sg_order: int = setting(2, "Savitzky-Golay polynomial degree.")
    cw_window: int = setting(7, "Confidence-weighted regression window (odd, frames).")
    cw_order: int = setting(2, "Confidence-weighted regression polynomial degree.")
    cw_robust_iterations: int = setting(
        1, "Rounds of outlier reweighting in the confidence-weighted regression (0 = none)."
    )
    ici_window_min: int = setting(5, "Adaptive-window regression: shortest window (odd, frames).")
    ici_window_max: int = setting(
        17, "Adaptive-window regression: longest window at most this many frames."
    )
    ici_window_step: int = setting(
        4, "Adaptive-window regression: growth from one window to the next (even, frames)."
    )
    ici_order: int = setting(2, "Adaptive-window regression polynomial degree.")
    ici_threshold: float = setting(
        1.0,
        "Adaptive-window regression: confidence-interval half-width in noise standard "
        "deviations; larger keeps longer windows (smoother, more peak clipping).",
    )
    ici_robust_iterations: int = setting(
        1, "Rounds of outlier reweighting in the adaptive-window regression (0 = none)."
    )

    @property
    def ici_windows(self) -> tuple[int, ...]:
        """The adaptive-window regression's window lengths, shortest first."""
        return tuple(range(self.ici_window_min, self.ici_window_max + 1, self.ici_window_step))

    def __post_init__(self) -> None:
        if self.smoother not in SMOOTHERS:
            raise ValueError(
                f"refine.smoother must be one of {sorted(SMOOTHERS)}, got {self.smoother!r}"
            )
        if not 0.0 <= self.min_confidence <= 1.0:
            raise ValueError(f"refine.min_confidence must be in [0, 1], got {self.min_confidence}")
        for name in ("max_gap", "cw_robust_iterations", "ici_robust_iterations"):
            if getattr(self, name) < 0:
                raise ValueError(f"refine.{name} must be >= 0, got {getattr(self, name)}")
        if self.flip_max_age < 1:
            raise ValueError(f"refine.flip_max_age must be >= 1, got {self.flip_max_age}")
        for name in ("flip_ratio", "one_euro_min_cutoff", "one_euro_d_cutoff", "ici_threshold"):
            if not getattr(self, name) > 0:
                raise ValueError(f"refine.{name} must be > 0, got {getattr(self, name)}")
        if self.one_euro_beta < 0:
            raise ValueError(f"refine.one_euro_beta must be >= 0, got {self.one_euro_beta}")
        _check_window(
            "refine.sg_window", self.sg_window, self.sg_order, order_name="refine.sg_order"
        )
        _check_window(
            "refine.cw_window", self.cw_window, self.cw_order, order_name="refine.cw_order"
        )
        if self.cw_window < 2 * self.cw_order + 1:
            raise ValueError(
                f"refine.cw_window must be at least 2 * refine.cw_order + 1, got {self.cw_window}"
            )
        if self.ici_window_step < 2 or self.ici_window_step % 2:
            raise ValueError(
                f"refine.ici_window_step must be a positive even number, got {self.ici_window_step}"
            )
        if self.ici_window_max < self.ici_window_min:
            raise ValueError(
                f"refine.ici_window_max ({self.ici_window_max}) must be at least "
                f"refine.ici_window_min ({self.ici_window_min})"
            )
        _check_window(
            "refine.ici_window_min",
            self.ici_window_min,
            self.ici_order,
            order_name="refine.ici_order",
        )
        if self.ici_window_min < 2 * self.ici_order + 1:
            raise ValueError(
                "refine.ici_window_min must be at least 2 * refine.ici_order + 1, "
                f"got {self.ici_window_min}"
            )


class Smoother(Protocol):
    """A smoother as :func:`refine` calls it: (T, J, 2) keypoints, (T, J) confidence, fps and the
    config in; (T, J, 2) smoothed keypoints out, NaN where the input is."""

    def __call__(
        self, keypoints: np.ndarray, confidence: np.ndarray, fps: float, config: RefineConfig
    ) -> np.ndarray: ...


def _no_smoothing(
    keypoints: np.ndarray, confidence: np.ndarray, fps: float, config: RefineConfig
) -> np.ndarray:
    return np.array(keypoints, dtype=np.float64, copy=True)


def _one_euro(
    keypoints: np.ndarray, confidence: np.ndarray, fps: float, config: RefineConfig
) -> np.ndarray:
    return one_euro(
        keypoints,
        fps,
        min_cutoff=config.one_euro_min_cutoff,
        beta=config.one_euro_beta,
        d_cutoff=config.one_euro_d_cutoff,
    )


def _savitzky_golay(
    keypoints: np.ndarray, confidence: np.ndarray, fps: float, config: RefineConfig
) -> np.ndarray:
    return savitzky_golay(keypoints, window=config.sg_window, order=config.sg_order)


def _confidence_weighted(
    keypoints: np.ndarray, confidence: np.ndarray, fps: float, config: RefineConfig
) -> np.ndarray:
    return confidence_weighted(
        keypoints,
        confidence,
        window=config.cw_window,
        order=config.cw_order,
        robust_iterations=config.cw_robust_iterations,
    )


def _adaptive_window(
    keypoints: np.ndarray, confidence: np.ndarray, fps: float, config: RefineConfig
) -> np.ndarray:
    return adaptive_window(
        keypoints,
        confidence,
        windows=config.ici_windows,
        order=config.ici_order,
        threshold=config.ici_threshold,
        robust_iterations=config.ici_robust_iterations,
    )


# The smoothers RefineConfig.smoother can name.
SMOOTHERS: Mapping[str, Smoother] = {
    "none": _no_smoothing,
    "one_euro": _one_euro,
    "savitzky_golay": _savitzky_golay,
    "confidence_weighted": _confidence_weighted,
    "adaptive_window": _adaptive_window,
}


# eq=False: fields are arrays, whose == is elementwise; compare by identity.
@dataclass(frozen=True, eq=False)
class RefineResult:
    """One fighter's refined keypoints over a window of frames.

    Attributes:
        keypoints: (T, J, 2) refined pixels; NaN where a joint stayed missing (gaps longer than
            max_gap, the window's ends, untrusted points that could not be filled).
        confidence: (T, J) in [0, 1]: the input's for trusted points, reduced for filled ones,
            0 where NaN.
        filled_mask: (T, J) bool, the points made by interpolation.
        flips_fixed: frames in which at least one limb group's left/right labels were swapped back.
        filled: number of filled joint-frames.
        jitter_before: jitter_px of the input keypoints (px / frame²).
        jitter_after: jitter_px of the refined keypoints (px / frame²).
    """

    keypoints: np.ndarray
    confidence: np.ndarray
    filled_mask: np.ndarray
    flips_fixed: int
    filled: int
    jitter_before: float
    jitter_after: float


def refine(
    keypoints: np.ndarray,
    confidence: np.ndarray,
    fps: float,
    config: RefineConfig,
    perm: np.ndarray,
    *,
    groups: Sequence[np.ndarray] | None = None,
    bones: Sequence[tuple[int, int]] = (),
) -> RefineResult:
    """Fix left/right flips, fill short gaps and smooth one fighter's keypoints.

    Args:
        keypoints: (T, J, 2) pixels, NaN where missing.
        confidence: (T, J) in [0, 1], 0 where missing.
        fps: frame rate (Hz).
        config: the stage's RefineConfig.
        perm: (J,) mirror of each joint, from :func:`flip_permutation`.
        groups: limb groups deciding flips separately; pass ``flip_groups(BLAZEPOSE_33)`` for
            BlazePose, whose leg-only swaps a single whole-body group (the default) cannot see.
        bones: bones a swap may not cross (`fix_flips`); ``flip_bones(BLAZEPOSE_33)``.
    """
    kp, conf = _checked(keypoints, confidence)
    _check_positive("fps", fps)
    unflipped, unflipped_conf, flips = fix_flips(
        kp,
        conf,
        perm,
        groups=groups,
        bones=bones,
        min_confidence=config.min_confidence,
        ratio=config.flip_ratio,
        max_age=config.flip_max_age,
    )
    gapless, gapless_conf, filled = fill_gaps(
        unflipped, unflipped_conf, max_gap=config.max_gap, min_confidence=config.min_confidence
    )
    smoothed = SMOOTHERS[config.smoother](gapless, gapless_conf, fps, config)
    return RefineResult(
        keypoints=smoothed,
        confidence=gapless_conf,
        filled_mask=filled,
        flips_fixed=flips,
        filled=int(filled.sum()),
        jitter_before=jitter_px(kp),
        jitter_after=jitter_px(smoothed),
    )
