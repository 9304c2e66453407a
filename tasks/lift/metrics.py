"""How good a lifted 3D motion is: pose error against a truth, and physical plausibility.

Pure NumPy, no MuJoCo. Positions are metres in, millimetres or centimetres out as each
function's name says. Missing points are NaN and are left out of every average.

Shape letters: T frames, J joints (33 in BlazePose order unless stated), K points.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from models.pose.types import BLAZEPOSE_33


def _i(name: str) -> int:
    return BLAZEPOSE_33.index(name)


# The BlazePose-33 hips; their midpoint is the root MPJPE aligns on (and BlazePose's
# world-landmark origin).
HIPS: tuple[int, int] = (_i("left_hip"), _i("right_hip"))

# Pairs of BlazePose-33 landmarks that lie on one rigid segment of a human (and of our
# humanoid, whose head, torso, upper arms, forearm+hand, thighs, shins and feet are rigid
# bodies), so their distance should not change over a clip. The trunk (shoulder to hip)
# bends at the abdomen and is left out.
BLAZEPOSE_BONES: tuple[tuple[int, int], ...] = tuple(
    (_i(a), _i(b))
    for a, b in (
        ("left_ear", "right_ear"),
        ("nose", "left_ear"),
        ("nose", "right_ear"),
        ("left_shoulder", "right_shoulder"),
        ("left_hip", "right_hip"),
        *(
            (f"{s}_{a}", f"{s}_{b}")
            for s in ("left", "right")
            for a, b in (
                ("shoulder", "elbow"),
                ("elbow", "wrist"),
                ("wrist", "index"),
                ("wrist", "pinky"),
                ("hip", "knee"),
                ("knee", "ankle"),
                ("ankle", "heel"),
                ("ankle", "foot_index"),
                ("heel", "foot_index"),
            )
        ),
    )
)

# Each foot's sole landmarks (heel, toe tip), left then right.
SOLES: tuple[tuple[int, int], tuple[int, int]] = (
    (_i("left_heel"), _i("left_foot_index")),
    (_i("right_heel"), _i("right_foot_index")),
)


def _points(name: str, value: np.ndarray, ndim: int = 3) -> np.ndarray:
    """`value` as float64 of `ndim` dimensions ending in 3, or ValueError naming `name`."""
    array = np.asarray(value, dtype=np.float64)
    if array.ndim != ndim or array.shape[-1] != 3:
        letters = "(T, J, 3)" if ndim == 3 else f"({', '.join(['T'] * (ndim - 1))}, 3)"
        raise ValueError(f"{name} must have shape {letters}, got {array.shape}")
    return array


def _pair(pred: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p = _points("pred", pred)
    t = _points("truth", truth)
    if p.shape != t.shape:
        raise ValueError(f"pred and truth must have the same shape, got {p.shape} and {t.shape}")
    return p, t


def _mean_error_mm(p: np.ndarray, t: np.ndarray, what: str) -> float:
    error = np.linalg.norm(p - t, axis=-1)
    if not np.isfinite(error).any():
        raise ValueError(f"{what}: no joint is finite in both pred and truth")
    return float(np.nanmean(error) * 1000.0)


def mpjpe_mm(
    pred: np.ndarray,
    truth: np.ndarray,
    *,
    align: str = "root",
    root: Sequence[int] = HIPS,
) -> float:
    """Mean per-joint position error in millimetres (Ionescu et al., Human3.6M, TPAMI 2014).

    With ``align="root"`` each frame of both skeletons is first moved so that its root (the
    mean of the `root` joints, by default BlazePose's hip centre) is at the origin, the
    usual protocol for monocular 3D pose; ``align="none"`` compares world positions as given.

    Args:
        pred: (T, J, 3) predicted points in metres; NaN where missing.
        truth: (T, J, 3) true points in metres; NaN where missing.
        align: "root" or "none".
        root: joint indices whose mean is the root (both must be finite in a frame for
            that frame to count).

    Returns:
        The mean over frames and joints of |pred - truth|, over the joints finite in both.

    Raises:
        ValueError: naming the bad argument, or if no joint is finite in both.
    """
    p, t = _pair(pred, truth)
    if align == "root":
        index = np.asarray(root, dtype=int)
        if index.ndim != 1 or index.size == 0 or index.min() < 0 or index.max() >= p.shape[1]:
            raise ValueError(f"root must be joint indices in [0, {p.shape[1]}), got {root!r}")
        # A frame whose root is NaN in either skeleton becomes NaN and drops out.
        p = p - p[:, index].mean(axis=1, keepdims=True)
        t = t - t[:, index].mean(axis=1, keepdims=True)
    elif align != "none":
        raise ValueError(f"align must be 'root' or 'none', got {align!r}")
    return _mean_error_mm(p, t, "mpjpe_mm")


def procrustes_align(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Each frame of `pred` moved onto `truth` by the best similarity transform.

    Minimises sum_j |s R p_j + c - t_j|^2 over scale s > 0, rotation R (det +1) and
    translation c, per frame, over the joints finite in both: Umeyama, "Least-squares
    estimation of transformation parameters between two point patterns", TPAMI 1991,
    eqs. 40-42. The sign correction S = diag(1, 1, det(U) det(V)) keeps R a rotation
    when the best orthogonal fit would be a reflection.

    Args:
        pred: (T, J, 3) points; NaN where missing.
        truth: (T, J, 3) points; NaN where missing.

    Returns:
        (T, J, 3) aligned `pred`; NaN where `pred` is NaN, and whole frames with fewer
        than 3 joints finite in both.
    """
    p, t = _pair(pred, truth)
    valid = np.isfinite(p).all(-1) & np.isfinite(t).all(-1)  # (T, J)
    w = valid.astype(np.float64)[..., None]
    n = w.sum(axis=1, keepdims=True)  # (T, 1, 1)
    safe_n = np.maximum(n, 1.0)
    p0 = np.where(valid[..., None], p, 0.0)
    t0 = np.where(valid[..., None], t, 0.0)
    mu_p = (w * p0).sum(axis=1, keepdims=True) / safe_n
    mu_t = (w * t0).sum(axis=1, keepdims=True) / safe_n
    pc = w * (p0 - mu_p)
    tc = w * (t0 - mu_t)
    cov = np.einsum("tji,tjk->tik", tc, pc) / safe_n  # Sigma_xy = E[(t - mu_t)(p - mu_p)^T]
    u, sigma, vt = np.linalg.svd(cov)
    sign = np.sign(np.linalg.det(u) * np.linalg.det(vt))
    sign = np.where(sign == 0, 1.0, sign)
    s_diag = np.ones_like(sigma)
    s_diag[:, 2] = sign
    rotation = u @ (s_diag[..., None] * vt)  # U S V^T
    var_p = (pc**2).sum(axis=(1, 2)) / safe_n[:, 0, 0]
    scale = (sigma * s_diag).sum(-1) / np.maximum(var_p, 1e-300)
    aligned = scale[:, None, None] * np.einsum("tik,tjk->tji", rotation, p - mu_p) + mu_t
    enough = (n[:, 0, 0] >= 3) & (var_p > 0)
    return np.where(enough[:, None, None], aligned, np.nan)


def pa_mpjpe_mm(pred: np.ndarray, truth: np.ndarray) -> float:
    """Procrustes-aligned MPJPE in millimetres: MPJPE after `procrustes_align` per frame.

    Blind to the skeleton's scale, global rotation and position, so it measures the
    pose alone (the protocol-2 error of Human3.6M papers).

    Args:
        pred: (T, J, 3) predicted points in metres; NaN where missing.
        truth: (T, J, 3) true points in metres; NaN where missing.

    Returns:
        The mean aligned per-joint error over the joints finite in both.
    """
    aligned = procrustes_align(pred, truth)
    return _mean_error_mm(aligned, np.asarray(truth, dtype=np.float64), "pa_mpjpe_mm")


def sole_points(points: np.ndarray) -> np.ndarray:
    """Each foot's sole point: the midpoint of its heel and toe-tip landmarks.

    The midpoint rests on the floor through a flat-footed stance and does not jump as a
    "lowest of heel and toe" point would when the two swap, which `foot_skating_cm_per_frame`
    would count as a slide.

    Args:
        points: (T, 33, 3) BlazePose-order points in metres, z up.

    Returns:
        (T, 2, 3) left and right sole points.
    """
    p = _points("points", points)
    if p.shape[1] != len(BLAZEPOSE_33):
        raise ValueError(f"points must have shape (T, 33, 3) in BlazePose order, got {p.shape}")
    return np.stack([(p[:, h] + p[:, toe]) / 2 for h, toe in SOLES], axis=1)


def foot_skating_cm_per_frame(foot_positions: np.ndarray, *, height: float = 0.035) -> float:
    """Foot skating error (FSE) in centimetres per frame.

    Bhuvaneshwara, "Simulating Fast-Movements with Mixture-of-Expert Models: An Interactive
    Boxing Controller", MSc thesis, Saarland University, 2021, eq. 6.7, after Ling et al.,
    "Character Controllers Using Motion VAEs", ACM TOG 39(4), 2020:

        FSE = 1/2 sum_l d_l (2 - 2^(h_l / H))

    for each pair of consecutive frames, averaged here over the pairs; d_l is foot l's
    displacement between the two frames, h_l its mean height over them and H the height
    threshold (3.5 cm in the thesis). Choices the text leaves open:
    - d is the horizontal (x, y) displacement: a foot lifting straight up does not skate.
    - The weight counts only below H (above it 2 - 2^(h/H) < 0, and a foot in the air
      cannot skate), so it is 0 there.
    - h is clipped at 0 from below, so a foot under the floor weighs as one on it (1),
      not up to 2; `floor_penetration_mm` reports penetration.

    Args:
        foot_positions: (T, 2, 3) a point on each foot's sole (e.g. `sole_points`), metres,
            z up with the floor at z = 0; T >= 2. NaN pairs are left out.
        height: the threshold H in metres.

    Returns:
        Mean skating over feet and consecutive-frame pairs, cm per frame.
    """
    f = np.asarray(foot_positions, dtype=np.float64)
    if f.ndim != 3 or f.shape[1:] != (2, 3) or f.shape[0] < 2:
        raise ValueError(f"foot_positions must have shape (T >= 2, 2, 3), got {f.shape}")
    if not (np.isfinite(height) and height > 0):
        raise ValueError(f"height must be a positive threshold in metres, got {height!r}")
    d = np.linalg.norm(f[1:, :, :2] - f[:-1, :, :2], axis=-1)  # (T-1, 2)
    h = np.clip((f[1:, :, 2] + f[:-1, :, 2]) / 2, 0.0, height)  # the weight is 0 from height up
    weight = np.where(h < height, 2.0 - np.exp2(h / height), 0.0)
    skate = d * weight
    if not np.isfinite(skate).any():
        raise ValueError("foot_positions has no finite pair of consecutive frames")
    return float(np.nanmean(skate) * 100.0)


def floor_penetration_mm(lowest_points: np.ndarray) -> tuple[float, float]:
    """How far a body sinks into the floor (z = 0).

    Args:
        lowest_points: (T, K, 3) points that should not go below the floor (sole points,
            foot geom corners), metres, z up.

    Returns:
        (max, mean) in millimetres of each frame's deepest point below z = 0 (0 for a
        frame with every point above the floor): the worst frame, and the mean over frames.
    """
    p = _points("lowest_points", lowest_points)
    depth = np.maximum(-p[..., 2], 0.0)  # (T, K)
    if not np.isfinite(depth).any():
        raise ValueError("lowest_points has no finite point")
    per_frame = np.where(np.isfinite(depth), depth, -np.inf).max(axis=1)  # NaN points skipped
    per_frame = per_frame[np.isfinite(per_frame)]
    return float(per_frame.max() * 1000.0), float(per_frame.mean() * 1000.0)


def bone_length_std_mm(
    points: np.ndarray, bones: Sequence[tuple[int, int]] = BLAZEPOSE_BONES
) -> float:
    """How much rigid segments stretch over a clip: the mean over bones of the std over frames
    of each bone's length, in millimetres (0 for a rigid skeleton such as the humanoid's).

    Args:
        points: (T, J, 3) points in metres; NaN where missing.
        bones: (i, j) joint index pairs, each on one rigid segment.

    Returns:
        Mean over bones (with at least 2 finite frames) of the length's standard deviation.
    """
    p = _points("points", points)
    pairs = np.asarray(bones, dtype=int)
    if pairs.ndim != 2 or pairs.shape[1] != 2 or pairs.min() < 0 or pairs.max() >= p.shape[1]:
        raise ValueError(
            f"bones must be (i, j) pairs of indices in [0, {p.shape[1]}), got {bones!r}"
        )
    lengths = np.linalg.norm(p[:, pairs[:, 0]] - p[:, pairs[:, 1]], axis=-1)  # (T, B)
    counted = np.isfinite(lengths).sum(axis=0) >= 2
    if not counted.any():
        raise ValueError("points measure no bone in 2 or more frames")
    return float(np.nanstd(lengths[:, counted], axis=0).mean() * 1000.0)


def jitter_m_s2(points: np.ndarray, fps: float) -> float:
    """Mean joint acceleration magnitude in m/s^2, by central second differences.

    Noise from frame-by-frame estimation shows up as large accelerations; smooth true
    motion has small ones (a fast punch peaks near 100 m/s^2, but its mean is far lower).

    Args:
        points: (T, J, 3) points in metres, T >= 3; NaN where missing.
        fps: frames per second.

    Returns:
        Mean over frames and joints of |p[t+1] - 2 p[t] + p[t-1]| * fps^2.
    """
    p = _points("points", points)
    if p.shape[0] < 3:
        raise ValueError(f"points must have at least 3 frames, got {p.shape[0]}")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive frame rate, got {fps!r}")
    accel = np.linalg.norm(p[2:] - 2 * p[1:-1] + p[:-2], axis=-1) * fps**2
    if not np.isfinite(accel).any():
        raise ValueError("points has no joint finite in 3 consecutive frames")
    return float(np.nanmean(accel))
