"""Temporal refinement of one fighter's 2D keypoints: undo left/right flips, fill gaps, smooth.

Everything here is a pure NumPy function over a window of frames; inputs are never modified.

Shape letters: T frames, J joints (33 for BlazePose), P polynomial coefficients.
Layout: ``keypoints`` (T, J, 2) float image pixels (x right, y down), NaN where the joint was not
observed; ``confidence`` (T, J) in [0, 1], 0 where missing.

Order of work in :func:`refine`: flips first (a swapped frame would otherwise be interpolated
and smoothed into its neighbours), then gaps (so the smoothers see short gaps bridged), then one
smoother picked by name from :data:`SMOOTHERS` (the smoothers are in `tasks.pose.smoothing`).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from tasks.pose.checks import check_positive, checked
from tasks.pose.config import SMOOTHER_NAMES, RefineConfig
from tasks.pose.smoothing import (
    MIN_WEIGHT,
    adaptive_window,
    confidence_weighted,
    one_euro,
    savitzky_golay,
)

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
    spikes: np.ndarray,
) -> np.ndarray:
    """(T,) bool frames where ``joints``' left/right labels are to be swapped (see fix_flips);
    never a frame of ``vetoed``. ``spikes`` (T, len(joints)): joints that leap away for one
    frame and come back (`_spikes`)."""
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
            w = np.maximum(weight[use], MIN_WEIGHT)
            as_is = np.sum(w * np.linalg.norm(cur[use] - ref[use], axis=1))
            mirrored = np.sum(w * np.linalg.norm(cur[use] - ref[mirror_k[use]], axis=1))
            swap[t] = mirrored < ratio * as_is and not vetoed[t]
        else:
            current += 1  # no usable reference: a new chain starts, its parity unknown
        segment[t] = current
        # The label a point carries after the decision: a swap moves joint j's point to mirror(j).
        label = mirror_k if swap[t] else np.arange(len(joints))
        # A joint that leaps away for a frame is a reference only where it leapt onto its
        # mirror (a flip, swapped back): a garbled frame's (shoulders crossed, a hand 300 px
        # off, neither as-is nor mirrored) made every later frame look flipped, and 45 frames
        # of a walker's arms came out swapped.
        keep = valid & (swap[t] | ~spikes[t])
        ref[label[keep]] = cur[keep]
        ref_frame[label[keep]] = t
    # A chain's parity is set by its first frame, which may itself be flipped; flips are the
    # exception, so a chain where most frames were swapped started flipped and is inverted.
    for s in range(current + 1):
        in_segment = segment == s
        inverted = in_segment & ~swap
        # An inversion that would cross bones the model left apart is not the better reading.
        if 2 * swap[in_segment].sum() > in_segment.sum() and not (inverted & vetoed).any():
            swap[in_segment] = ~swap[in_segment]
    return swap


# A spike moves a joint further from the midpoint of its two neighbours than both this share
# of the body's height in the image and the neighbours' distance from each other.
SPIKE_SHARE = 0.1


def _spikes(kp: np.ndarray) -> np.ndarray:
    """(T, J) bool: joints of (T, J, 2) ``kp`` that leap away for one frame and come back."""
    spikes = np.zeros(kp.shape[:2], dtype=bool)
    if len(kp) < 3:
        return spikes
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # frames with no joint seen
        height = np.nanmax(kp[..., 1], axis=1) - np.nanmin(kp[..., 1], axis=1)
        off = np.linalg.norm(kp[1:-1] - (kp[:-2] + kp[2:]) / 2, axis=-1)
        span = np.linalg.norm(kp[2:] - kp[:-2], axis=-1)
        spikes[1:-1] = (off > span) & (off > SPIKE_SHARE * height[1:-1, None])
    return spikes


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
    kp, conf = checked(keypoints, confidence)
    perm = _check_perm(perm, kp.shape[1])
    groups_checked = _check_groups(groups, perm)
    check_positive("ratio", ratio)
    if max_age < 1:
        raise ValueError(f"max_age must be >= 1 frame, got {max_age}")
    out_kp, out_conf = kp.copy(), conf.copy()
    any_swap = np.zeros(kp.shape[0], dtype=bool)
    spikes = _spikes(kp)
    for joints in groups_checked:
        swap = _group_swaps(
            kp,
            conf,
            perm,
            joints,
            min_confidence=min_confidence,
            ratio=ratio,
            max_age=max_age,
            vetoed=_invents_cross(kp, out_kp, perm, joints, bones),
            spikes=spikes[:, joints],
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
    kp, conf = checked(keypoints, confidence)
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
# Metric


def jitter_px(keypoints: np.ndarray, *, cuts: Sequence[int] = ()) -> float:
    """Mean magnitude of the 2D second difference x[t+1] - 2 x[t] + x[t-1] (px / frame²).

    Taken over every joint and frame t whose three frames are all observed and in one shot;
    NaN if there is none. This is the pose stage's ``jitter_px`` metric. Real motion has some
    (a punch's turn-around), so lower is better only down to the truth's own value.

    Args:
        keypoints: (T, J, 2) pixels, NaN where missing.
        cuts: frames where a shot starts: no difference is taken across them.
    """
    kp, _ = checked(keypoints)
    if kp.shape[0] < 3:
        return float("nan")
    second = kp[2:] - 2.0 * kp[1:-1] + kp[:-2]  # centred on frames 1 .. T-2
    centre = np.arange(1, len(kp) - 1)
    for cut in cuts:
        second[(centre == cut - 1) | (centre == cut)] = np.nan
    size = np.linalg.norm(second, axis=2)
    size = size[np.isfinite(size)]
    return float(size.mean()) if size.size else float("nan")


# ---------------------------------------------------------------------------------------------
# Configured stage step


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
assert tuple(SMOOTHERS) == SMOOTHER_NAMES, "RefineConfig names the smoothers"


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
    cuts: Sequence[int] = (),
) -> RefineResult:
    """Fix left/right flips, fill short gaps and smooth one fighter's keypoints.

    Each shot is refined on its own: ``cuts`` are the frames where a new shot starts, and no
    flip, gap or smoother reaches across one (after a cut the fighter is elsewhere in the
    picture, seen by another camera; smoothed across it, the frames by the cut were drawn
    towards the other shot's place, and the sample's adversary was lifted up to 34 cm off in
    depth: tests/test_shot_cuts.py).

    Args:
        keypoints: (T, J, 2) pixels, NaN where missing.
        confidence: (T, J) in [0, 1], 0 where missing.
        fps: frame rate (Hz).
        config: the stage's RefineConfig.
        perm: (J,) mirror of each joint, from :func:`flip_permutation`.
        groups: limb groups deciding flips separately; pass ``flip_groups(BLAZEPOSE_33)`` for
            BlazePose, whose leg-only swaps a single whole-body group (the default) cannot see.
        bones: bones a swap may not cross (`fix_flips`); ``flip_bones(BLAZEPOSE_33)``.
        cuts: frames (0 < cut < T) where a shot starts.
    """
    kp, conf = checked(keypoints, confidence)
    check_positive("fps", fps)
    bounds = sorted({int(c) for c in cuts})
    if any(not 0 < c < len(kp) for c in bounds):
        raise ValueError(f"cuts must lie inside the {len(kp)} frames, got {list(cuts)}")
    parts = [
        _refine_shot(kp[a:b], conf[a:b], fps, config, perm, groups, bones)
        for a, b in zip([0, *bounds], [*bounds, len(kp)], strict=True)
    ]
    smoothed = np.concatenate([p[0] for p in parts])
    filled = np.concatenate([p[2] for p in parts])
    return RefineResult(
        keypoints=smoothed,
        confidence=np.concatenate([p[1] for p in parts]),
        filled_mask=filled,
        flips_fixed=sum(p[3] for p in parts),
        filled=int(filled.sum()),
        jitter_before=jitter_px(kp, cuts=bounds),
        jitter_after=jitter_px(smoothed, cuts=bounds),
    )


def _refine_shot(
    kp: np.ndarray,
    conf: np.ndarray,
    fps: float,
    config: RefineConfig,
    perm: np.ndarray,
    groups: Sequence[np.ndarray] | None,
    bones: Sequence[tuple[int, int]],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """:func:`refine`'s work on one shot: smoothed keypoints, confidence, filled mask, flips."""
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
    return smoothed, gapless_conf, filled, flips
