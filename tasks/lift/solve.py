"""One fighter's 2D keypoints and BlazePose world landmarks to a clean humanoid motion.

Three pure steps, each callable on its own:

1. `lift_fighter`: 3D joints per frame in the world frame. The start is BlazePose's world
   landmarks, turned from camera axes into world axes and placed at the hip centre; a batched
   L-BFGS over every frame's joint positions then minimises (`lift_energy`)
   confidence-weighted reprojection error + bone-length constancy (one length per bone over
   the clip) + temporal smoothness (second differences) + closeness to the landmarks' shape,
   and, once foot contacts are detected (`detect_contacts`, from foot height and speed), feet
   on the floor without sliding. Temporal fusion of monocular estimates with reprojection and
   bone/smoothness priors follows e.g. Arnab et al., "Exploiting temporal context for 3D human
   pose estimation in the wild", CVPR 2019, §3, and Peng et al., "SFV: Reinforcement learning
   of physical skills from videos", SIGGRAPH Asia 2018, §4.2 (without SMPL: the unknowns are
   joint positions). `Lifter` is the interface a learned temporal lifter (ONNX) can fill.
2. `fit_humanoid`: inverse kinematics of the boxer humanoid to those joints: an analytic
   first guess of each body's rotation from the joints (`body_rotations_from_points`), then
   damped least squares (Levenberg-Marquardt) with the geometric site Jacobian, batched over
   all frames, joint limits kept by clamping the step (an active set).
3. `cleanup`: in MuJoCo, what a body cannot do is removed: jitter (a zero-phase Gaussian
   filter on qpos), feet through or above the floor during contact and foot skating (the
   root follows the contact feet to their anchors on the floor, then leg IK pins each
   contact foot there with smooth blending), one fighter inside the other (the roots are
   pushed apart along the line between them, minimally and smoothly, with geom-geom depths
   from capsule distances checked against MuJoCo's contacts in the tests), and any remaining
   floor penetration of any geom. qvel comes from `mj_differentiatePos`. `cleanup_pair` does
   both fighters of a shot.

Shape letters: T frames, J = 33 BlazePose landmarks (`BLAZEPOSE_33` order), B bones,
S humanoid sites, G geoms, D degrees of freedom. Units: metres, seconds, radians; image
coordinates in pixels. World frame: z up, floor z = 0. Cameras: OpenCV pinhole,
``x_cam = R @ x_world + t`` (x right, y down, z forward).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, replace
from typing import Protocol, runtime_checkable

import mujoco
import numpy as np
import torch

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.kinematics import (
    BLAZEPOSE_TO_SITE,
    BODY_NAMES,
    JOINT_LAYOUT,
    NQ,
    NUM_ACTUATED,
    NUM_BODIES,
    NV,
    ROOT_POS,
    ROOT_QUAT,
    SITE_NAMES,
    HumanoidIndex,
    axis_angle_matrix,
    humanoid_index,
    keypoint_positions,
    matrix_to_quat,
    qpos_from_body_rotations,
    quat_to_matrix,
)
from models.pose.types import BLAZEPOSE_33
from tasks.lift.camera import root_translations
from tasks.lift.config import LiftConfig
from tasks.lift.metrics import (
    BLAZEPOSE_BONES,
    SOLES,
    foot_skating_cm_per_frame,
    jitter_m_s2,
)
from tasks.lift.motion import gaussian_smooth, velocities

NUM_KEYPOINTS = len(BLAZEPOSE_33)


def _k(name: str) -> int:
    return BLAZEPOSE_33.index(name)


# BlazePose's hips; their midpoint is the hip centre (BlazePose's world-landmark origin and
# the humanoid's pelvis origin).
HIPS: tuple[int, int] = (_k("left_hip"), _k("right_hip"))

# Landmark pairs on one rigid segment of the humanoid (head, shoulder line, hip line, upper
# arms, forearm + glove, thighs, shins, feet): each keeps one length over a clip in the lift.
# The metric's rigid pairs, plus the face and the gloved hand, which are rigid on the humanoid.
LIFT_BONES: tuple[tuple[int, int], ...] = BLAZEPOSE_BONES + tuple(
    (_k(a), _k(b))
    for a, b in (
        ("left_eye", "right_eye"),
        ("mouth_left", "mouth_right"),
        ("nose", "mouth_left"),
        ("nose", "mouth_right"),
        ("left_wrist", "left_thumb"),
        ("right_wrist", "right_thumb"),
        ("left_elbow", "left_index"),
        ("right_elbow", "right_index"),
    )
)

# Humanoid sites on the head: their IK weight is `LiftConfig.ik_face_weight`.
_FACE_SITES = frozenset(
    ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "mouth_left", "mouth_right")
)


# ---------------------------------------------------------------------------------------------
# Config and results


@dataclass(frozen=True, eq=False)
class Lifted3D:
    """One fighter's lifted motion.

    Attributes:
        points: (T, 33, 3) BlazePose-order joints in the world frame, metres.
        bones: the fighter's segment lengths measured on `points` (`BoneLengths.from_points`).
        contacts: (T, 2) bool, left and right foot on the floor.
    """

    points: np.ndarray
    bones: BoneLengths
    contacts: np.ndarray


@dataclass(frozen=True, eq=False)
class Cleaned:
    """One fighter's humanoid motion after physics cleanup.

    Attributes:
        qpos: (T, 35) humanoid configurations (root position, root quaternion w-x-y-z,
            28 hinge angles within their ranges).
        qvel: (T, 34) velocities at the same frames: root linear velocity (world), root
            angular velocity (pelvis frame), hinge rates; central differences.
        points: (T, 33, 3) the humanoid's sites standing for the BlazePose landmarks, metres.
        contacts: (T, 2) bool, left and right foot in contact as the cleanup used them.
        settle: (T,) how far `settle_on_floor` lowered the root in each frame, metres.
        metrics: name -> value, before and after (``*_before``, ``*_after``):
            ``floor_penetration_mm`` (deepest geom below the floor, max over frames),
            ``foot_height_cm`` (median over frames of the lower foot's lowest point),
            ``foot_skating_cm_per_frame`` (`tasks.lift.metrics.foot_skating_cm_per_frame`,
            the height-weighted FSE, on the heel-toe midpoints of the humanoid's feet),
            ``contact_slide_cm_per_frame`` (mean horizontal slide of those midpoints for
            feet in contact in two consecutive frames, by the contacts used),
            ``jitter_m_s2`` (`tasks.lift.metrics.jitter_m_s2` of the landmarks),
            ``interpenetration_mm`` (deepest overlap with the other fighter, max over
            frames; only with one); and ``contact_share`` and ``floor_settle_cm`` (median
            drop of `settle_on_floor`).
    """

    qpos: np.ndarray
    qvel: np.ndarray
    points: np.ndarray
    contacts: np.ndarray
    settle: np.ndarray
    metrics: dict[str, float]


@runtime_checkable
class Lifter(Protocol):
    """Turns one fighter's 2D keypoints and BlazePose world landmarks into 3D (`Lifted3D`).

    `OptimisationLifter` is the optimiser of this module; a learned temporal lifter (an ONNX
    model reading a window of 2D keypoints, e.g. VideoPose3D or MotionBERT) can stand in its
    place: same arguments as `lift_fighter`, same result.
    """

    def __call__(
        self,
        keypoints_2d: np.ndarray,
        confidence: np.ndarray,
        world_landmarks: np.ndarray,
        K: np.ndarray,
        R: np.ndarray,
        t: np.ndarray,
        *,
        fps: float,
        root_init: np.ndarray | None = None,
    ) -> Lifted3D: ...


@dataclass(frozen=True)
class OptimisationLifter:
    """The `Lifter` that runs `lift_fighter` with a fixed config."""

    config: LiftConfig = LiftConfig()  # noqa: RUF009 (frozen, so a safe default)

    def __call__(
        self,
        keypoints_2d: np.ndarray,
        confidence: np.ndarray,
        world_landmarks: np.ndarray,
        K: np.ndarray,
        R: np.ndarray,
        t: np.ndarray,
        *,
        fps: float,
        root_init: np.ndarray | None = None,
    ) -> Lifted3D:
        return lift_fighter(
            keypoints_2d,
            confidence,
            world_landmarks,
            K,
            R,
            t,
            fps=fps,
            config=self.config,
            root_init=root_init,
        )


# ---------------------------------------------------------------------------------------------
# Checks and small helpers


def _array(name: str, value: np.ndarray, shape: tuple[int | None, ...]) -> np.ndarray:
    """`value` as float64, or ValueError naming `name` unless its shape matches (None: any)."""
    array = np.asarray(value, dtype=np.float64)
    if array.ndim != len(shape) or any(
        want is not None and got != want for got, want in zip(array.shape, shape, strict=True)
    ):
        letters = "(" + ", ".join("T" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name} must have shape {letters}, got {array.shape}")
    return array


def _check_fps(fps: float) -> float:
    if (
        isinstance(fps, bool)
        or not isinstance(fps, int | float)
        or not (math.isfinite(fps) and fps > 0)
    ):
        raise ValueError(f"fps must be a positive frame rate, got {fps!r}")
    return float(fps)


def _fill_missing(values: np.ndarray, name: str) -> np.ndarray:
    """(T, J, D) with non-finite rows of each joint filled by linear interpolation over time
    (held constant past the ends); ValueError naming `name` if a joint is never finite."""
    out = values.copy()
    frames = np.arange(len(values))
    finite = np.isfinite(values).all(-1)  # (T, J)
    for j in np.flatnonzero(~finite.all(0)):
        good = finite[:, j]
        if not good.any():
            raise ValueError(f"{name} has no finite value for landmark {BLAZEPOSE_33[j]!r}")
        for d in range(values.shape[-1]):
            out[~good, j, d] = np.interp(frames[~good], frames[good], values[good, j, d])
    return out


def clean_runs(mask: np.ndarray, min_frames: int) -> np.ndarray:
    """A boolean sequence with short gaps filled, then short runs dropped, per column.

    Args:
        mask: (T, ...) bool.
        min_frames: gaps (False runs between two True runs) and True runs shorter than this
            are flipped; 0 or 1 leaves `mask` as it is.

    Returns:
        (T, ...) bool, a new array.
    """
    m = np.array(mask, dtype=bool, copy=True)
    if min_frames <= 1 or m.size == 0:
        return m
    flat = m.reshape(len(m), -1)
    for column in flat.T:
        for value, fill in ((False, True), (True, False)):
            runs = _runs(column == value)
            for start, stop in runs:
                inner = value or (start > 0 and stop < len(column))  # gaps: between runs only
                if inner and stop - start < min_frames:
                    column[start:stop] = fill
    return flat.reshape(m.shape)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True in a 1-D bool array."""
    padded = np.concatenate([[False], mask, [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True))


def _max_then_mean(values: np.ndarray, half: int) -> np.ndarray:
    """A smooth upper envelope: a running max then a running mean, both over 2 half + 1 frames.

    Every output sample is >= the input at its frame (each running max that the mean averages
    covers the frame), so a correction that must reach at least `values` still does.

    Args:
        values: (T,) samples.
        half: half-width in frames; 0 returns a copy.
    """
    v = np.asarray(values, dtype=np.float64)
    if half <= 0 or len(v) == 0:
        return v.copy()
    padded = np.pad(v, half, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
    peak = windows.max(axis=1)
    padded = np.pad(peak, half, mode="edge")
    return np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1).mean(axis=1)


# ---------------------------------------------------------------------------------------------
# Lift: equations (torch, batched over frames)


def charbonnier(squared: torch.Tensor) -> torch.Tensor:
    """Charbonnier (pseudo-Huber) penalty of squared normalised residuals: 2 (sqrt(1 + r^2) - 1).

    Quadratic (r^2) for small r, linear (2 |r|) for outliers such as a mislabelled keypoint
    (Charbonnier et al., "Two deterministic half-quadratic regularization algorithms for
    computed imaging", ICIP 1994).
    """
    return 2.0 * (torch.sqrt(1.0 + squared) - 1.0)


def project_torch(points: torch.Tensor, K: torch.Tensor, R: torch.Tensor, t: torch.Tensor):
    """Pinhole projection: (..., 3) world points to (..., 2) pixels, pi(K (R x + t)).

    Depths are clamped at 1 mm so a point behind the camera gives a finite (large) error.
    """
    cam = points @ R.T + t
    uvw = cam @ K.T
    return uvw[..., :2] / uvw[..., 2:].clamp_min(1e-3)


def bone_lengths_torch(points: torch.Tensor, bones: torch.Tensor) -> torch.Tensor:
    """(T, J, 3) points and (B, 2) index pairs to (T, B) lengths (smooth at zero length)."""
    diff = points[:, bones[:, 0]] - points[:, bones[:, 1]]
    return torch.sqrt((diff * diff).sum(-1) + 1e-12)


def second_differences(points: torch.Tensor) -> torch.Tensor:
    """(T, ...) samples to (T - 2, ...) x[t+1] - 2 x[t] + x[t-1] (acceleration / fps^2)."""
    return points[2:] - 2.0 * points[1:-1] + points[:-2]


@dataclass(frozen=True, eq=False)
class LiftData:
    """The fixed inputs of `lift_energy`, as fp32 tensors.

    Attributes:
        keypoints_2d: (T, J, 2) pixels (0 where missing).
        weight: (T, J) reprojection weights (confidence, 0 where missing or too unsure).
        shape: (T, J, 3) world landmarks about their hip centre, in world axes, metres.
        K, R, t: (3, 3), (3, 3), (3,) the camera.
        bones: (B, 2) int64 landmark pairs (`LIFT_BONES`).
        fps: frames per second.
    """

    keypoints_2d: torch.Tensor
    weight: torch.Tensor
    shape: torch.Tensor
    K: torch.Tensor
    R: torch.Tensor
    t: torch.Tensor
    bones: torch.Tensor
    fps: float


def lift_energy(
    points: torch.Tensor,
    lengths: torch.Tensor,
    data: LiftData,
    config: LiftConfig,
    contacts: torch.Tensor | None = None,
) -> torch.Tensor:
    """The lift's objective per frame, E / T, for joints `points` and bone `lengths`.

    E = w_p sum_tj c_tj rho(|pi(x_tj) - u_tj|^2 / s_p^2)              reprojection
      + w_s sum_tj |x_tj - h_t - y_tj|^2 / s_s^2                         world-landmark shape
      + w_b sum_tb (|x_ti - x_tj| - L_b)^2 / s_b^2                       bone constancy
      + w_a [sum_tj |x_t+1,j - 2 x_tj + x_t-1,j|^2 / (s_a / fps^2)^2      smoothness
             + sum_t |h_t+1 - 2 h_t + h_t-1|^2 / (s_h / fps^2)^2]
      + w_c [(sum_t,f in contact (min sole z)^2 + sum_t,sole min(z, 0)^2) / s_f^2   floor
             + sum_t,f in contact at t and t+1 |m_t+1,f - m_tf|^2 / s_l^2]          no slide

    with c the reprojection weights, rho `charbonnier`, h_t the hip centre of x_t, y the world
    landmarks about their hip centre in world axes, L one length per bone over the clip, m
    the horizontal position of a sole's midpoint (between heel and toe tip), and the s the
    config's sigmas (s_h `root_accel_sigma_m_s2`, s_l `slide_sigma_m`).

    Args:
        points: (T, J, 3) world joints, metres.
        lengths: (B,) bone lengths, metres.
        data: the fixed inputs.
        config: weights and noise scales.
        contacts: (T, 2) float, 1 where the left / right foot is in contact; None leaves out
            the floor terms.

    Returns:
        A scalar tensor.
    """
    c = config
    frames = points.shape[0]
    uv = project_torch(points, data.K, data.R, data.t)
    squared = ((uv - data.keypoints_2d) ** 2).sum(-1) / c.reprojection_sigma_px**2
    energy = c.reprojection_weight * (data.weight * charbonnier(squared)).sum()
    hip = points[:, list(HIPS)].mean(1, keepdim=True)
    energy = energy + c.shape_weight * ((points - hip - data.shape) ** 2).sum() / (
        c.shape_sigma_m**2
    )
    stretch = bone_lengths_torch(points, data.bones) - lengths
    energy = energy + c.bone_weight * (stretch**2).sum() / c.bone_sigma_m**2
    if frames >= 3:
        scale = c.accel_sigma_m_s2 / data.fps**2
        root_scale = c.root_accel_sigma_m_s2 / data.fps**2
        smooth = (second_differences(points) ** 2).sum() / scale**2
        smooth = smooth + (second_differences(hip) ** 2).sum() / root_scale**2
        energy = energy + c.smoothness_weight * smooth
    if contacts is not None:
        soles = points[:, torch.tensor(SOLES)]  # (T, 2 feet, 2 points, 3)
        z = soles[..., 2]
        lowest = z.min(-1).values
        floor = (contacts * lowest**2).sum() + (torch.clamp(z, max=0.0) ** 2).sum()
        middle = soles[..., :2].mean(2)  # (T, 2, 2)
        both = contacts[1:] * contacts[:-1]
        slide = (both * ((middle[1:] - middle[:-1]) ** 2).sum(-1)).sum()
        energy = energy + c.contact_weight * (
            floor / c.floor_sigma_m**2 + slide / c.slide_sigma_m**2
        )
    return energy / frames


# ---------------------------------------------------------------------------------------------
# Lift


def detect_contacts(
    points: np.ndarray,
    *,
    fps: float,
    config: LiftConfig = LiftConfig(),  # noqa: B008 (frozen, so a safe default)
) -> np.ndarray:
    """Which foot is on the floor in each frame, from the 3D landmarks alone.

    A foot is in contact where its lowest sole landmark (heel or toe tip) is below
    `config.contact_height_m` and its sole's midpoint moves horizontally slower than
    `config.contact_speed_m_s` (`horizontal_speed`, over 5 frames); runs and gaps shorter than
    `config.contact_min_frames` are then removed (`clean_runs`).

    Args:
        points: (T, 33, 3) BlazePose-order world points, metres, z up, floor z = 0.
        fps: frames per second.
        config: the thresholds.

    Returns:
        (T, 2) bool, left foot then right foot.
    """
    p = _array("points", points, (None, NUM_KEYPOINTS, 3))
    fps = _check_fps(fps)
    soles = p[:, np.array(SOLES)]  # (T, 2, 2, 3)
    height = soles[..., 2].min(-1)
    middle = soles[..., :2].mean(2)  # (T, 2, 2)
    speed = horizontal_speed(middle, fps)
    raw = (height < config.contact_height_m) & (speed < config.contact_speed_m_s)
    return clean_runs(raw, config.contact_min_frames)


def horizontal_speed(positions: np.ndarray, fps: float, *, half: int = 2) -> np.ndarray:
    """Speed (m/s) from the displacement over 2 `half` frames centred on each frame
    (|x[t + half] - x[t - half]| / (2 half / fps), the window shrunk at the clip's ends),
    which averages out frame-to-frame noise that a one-frame difference would count.

    Args:
        positions: (T, ..., 2) or (T, ..., 3) positions; only the first two coordinates count.
        fps: frames per second.

    Returns:
        (T, ...) speeds; zeros for a single frame.
    """
    p = np.asarray(positions, dtype=np.float64)[..., :2]
    frames = len(p)
    if frames < 2:
        return np.zeros(p.shape[:-1])
    index = np.arange(frames)
    ahead = np.minimum(index + half, frames - 1)
    behind = np.maximum(index - half, 0)
    span = (ahead - behind).reshape(-1, *([1] * (p.ndim - 2)))
    return np.linalg.norm(p[ahead] - p[behind], axis=-1) / span * fps


def initial_points(
    keypoints_2d: np.ndarray,
    confidence: np.ndarray,
    world_landmarks: np.ndarray,
    K: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    *,
    root_init: np.ndarray | None = None,
) -> np.ndarray:
    """The lift's starting point: world landmarks in world axes at a hip-centre position.

    A direction v in camera axes is R.T v in the world. The hip centre is `root_init` when
    given, else, per frame, the camera-frame translation that best reprojects the landmarks
    onto the 2D keypoints (`tasks.lift.camera.root_translations`, linear least squares),
    moved into the world; frames it cannot place are interpolated.

    Args:
        keypoints_2d: (T, 33, 2) pixels, NaN where missing.
        confidence: (T, 33) in [0, 1].
        world_landmarks: (T, 33, 3) metres, camera axes, finite (fill gaps first).
        K, R, t: the camera.
        root_init: (T, 3) world hip-centre positions, or None.

    Returns:
        (T, 33, 3) world points, metres.
    """
    shape = world_landmarks - world_landmarks[:, list(HIPS)].mean(1, keepdims=True)
    if root_init is None:
        root_cam = root_translations(keypoints_2d, confidence, shape, K)  # (T, 3), NaN
        if not np.isfinite(root_cam).all(1).any():
            raise ValueError(
                "keypoints_2d: no frame has 3 or more confident keypoints to place the "
                "fighter; pass root_init"
            )
        root_cam = _fill_missing(root_cam[:, None], "keypoints_2d")[:, 0]
        root = (root_cam - t) @ R  # R.T (x_cam - t)
    else:
        root = root_init
    return shape @ R + root[:, None]


def lift_fighter(
    keypoints_2d: np.ndarray,
    confidence: np.ndarray,
    world_landmarks: np.ndarray,
    K: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    *,
    fps: float,
    config: LiftConfig = LiftConfig(),  # noqa: B008 (frozen, so a safe default)
    root_init: np.ndarray | None = None,
) -> Lifted3D:
    """Lift one fighter to 3D world joints: `initial_points`, then L-BFGS on `lift_energy`.

    The start is `initial_points` filtered over time (`gaussian_smooth`,
    `config.init_smooth_sigma_frames`). Two rounds, both over all frames at once in fp32:
    `config.iterations` without the floor terms, then contacts are detected on the result
    (`detect_contacts`) and `config.contact_iterations` more with them. The bone lengths of
    the energy are free variables (one per bone), started at their median over the initial
    frames. The iterations suit clips of up to ~300 frames; longer ones converge less far in
    as many (900 frames: PA-MPJPE 28 mm instead of 25), so lift long shots in chunks or raise
    the iterations.

    Args:
        keypoints_2d: (T, 33, 2) BlazePose 2D keypoints in pixels; NaN where missing.
        confidence: (T, 33) keypoint confidence in [0, 1]; 0 where missing.
        world_landmarks: (T, 33, 3) BlazePose world landmarks: metres, about the hip centre,
            camera axes (x right, y down, z away from the camera); NaN where missing (whole
            frames are interpolated from their neighbours).
        K: (3, 3) camera intrinsics.
        R: (3, 3) world-to-camera rotation.
        t: (3,) world-to-camera translation, x_cam = R x_world + t.
        fps: frames per second.
        config: weights, noise scales, iterations, contact thresholds.
        root_init: (T, 3) world hip-centre positions (e.g. from the feet on the floor), NaN
            where unknown (interpolated from the frames that have one), or None (or all
            NaN) to solve them from the 2D/3D scale.

    Returns:
        `Lifted3D` with world points, the bones measured on them and the contacts.

    Raises:
        ValueError: naming the argument whose shape or values are wrong.
    """
    kp = _array("keypoints_2d", keypoints_2d, (None, NUM_KEYPOINTS, 2))
    frames = len(kp)
    if frames == 0:
        raise ValueError("keypoints_2d must hold at least one frame, got 0")
    conf = _array("confidence", confidence, (frames, NUM_KEYPOINTS))
    landmarks = _array("world_landmarks", world_landmarks, (frames, NUM_KEYPOINTS, 3))
    K = _array("K", K, (3, 3))
    R = _array("R", R, (3, 3))
    t = _array("t", t, (3,))
    fps = _check_fps(fps)
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError("R must be a rotation matrix (orthonormal, det +1)")
    if not (np.isfinite(K).all() and np.isfinite(t).all()):
        raise ValueError("K and t must be finite")
    if np.isinf(kp).any():
        raise ValueError("keypoints_2d must be finite or NaN, got inf")
    conf = np.where(np.isfinite(conf), conf, 0.0)
    if (conf < 0).any() or (conf > 1).any():
        raise ValueError("confidence must hold values in [0, 1]")
    if root_init is not None:
        root_init = _array("root_init", root_init, (frames, 3))
        if np.isinf(root_init).any():
            raise ValueError("root_init must be finite or NaN, got inf")
        placed = np.isfinite(root_init).all(1)
        if not placed.any():
            root_init = None  # nothing placed: solve from the 2D/3D scale
        elif not placed.all():
            root_init = _fill_missing(root_init[:, None], "root_init")[:, 0]

    landmarks = _fill_missing(landmarks, "world_landmarks")
    seen = np.isfinite(kp).all(-1)
    conf = np.where(seen, conf, 0.0)
    x0 = initial_points(kp, conf, landmarks, K, R, t, root_init=root_init)
    x0 = gaussian_smooth(x0, config.init_smooth_sigma_frames)
    shape = (landmarks - landmarks[:, list(HIPS)].mean(1, keepdims=True)) @ R

    f32 = torch.float32
    weight = np.where(conf >= config.min_confidence, conf, 0.0)
    data = LiftData(
        keypoints_2d=torch.tensor(np.where(seen[..., None], kp, 0.0), dtype=f32),
        weight=torch.tensor(weight, dtype=f32),
        shape=torch.tensor(shape, dtype=f32),
        K=torch.tensor(K, dtype=f32),
        R=torch.tensor(R, dtype=f32),
        t=torch.tensor(t, dtype=f32),
        bones=torch.tensor(LIFT_BONES, dtype=torch.int64),
        fps=fps,
    )
    bones = np.array(LIFT_BONES)
    lengths0 = np.median(np.linalg.norm(x0[:, bones[:, 0]] - x0[:, bones[:, 1]], axis=-1), 0)
    points = torch.tensor(x0, dtype=f32)
    lengths = torch.tensor(lengths0, dtype=f32)
    with _one_torch_thread():
        points, lengths = _minimise(points, lengths, data, config, None, config.iterations)
        contacts = detect_contacts(points.numpy().astype(np.float64), fps=fps, config=config)
        if config.contact_iterations > 0:
            mask = torch.tensor(contacts, dtype=f32)
            points, lengths = _minimise(
                points, lengths, data, config, mask, config.contact_iterations
            )
            contacts = detect_contacts(points.numpy().astype(np.float64), fps=fps, config=config)
    out = points.numpy().astype(np.float64)
    return Lifted3D(points=out, bones=BoneLengths.from_points(out), contacts=contacts)


@contextlib.contextmanager
def _one_torch_thread():
    """Torch on one thread while the lift minimises: as fast on this 2-core machine (2.95 s
    against 2.97 s for both fighters of the sample) and, when other processes share the cores
    (two pipeline workers, four busy processes here), 2.95 s against 7-21 s for two threads.
    Results differ between thread counts (float32 sums split differently), so a fixed count
    also keeps a lift the same wherever it runs."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _minimise(
    points: torch.Tensor,
    lengths: torch.Tensor,
    data: LiftData,
    config: LiftConfig,
    contacts: torch.Tensor | None,
    iterations: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """L-BFGS with a strong-Wolfe line search on `lift_energy`; returns detached copies."""
    x = points.detach().clone().requires_grad_(True)
    lengths = lengths.detach().clone().requires_grad_(True)
    if iterations <= 0:
        return x.detach(), lengths.detach()
    optimiser = torch.optim.LBFGS(
        [x, lengths],
        lr=1.0,
        max_iter=iterations,
        max_eval=int(iterations * 1.25) + 1,
        history_size=20,
        tolerance_grad=1e-7,
        tolerance_change=1e-10,
        line_search_fn="strong_wolfe",
    )

    def closure() -> torch.Tensor:
        optimiser.zero_grad()
        energy = lift_energy(x, lengths, data, config, contacts)
        energy.backward()
        return energy

    with torch.enable_grad():
        optimiser.step(closure)
    return x.detach(), lengths.detach()


# ---------------------------------------------------------------------------------------------
# Humanoid kinematics in NumPy: FK and the geometric site Jacobian, batched over frames


@dataclass(frozen=True, eq=False)
class Skeleton:
    """Forward kinematics and site Jacobians of one boxer of a compiled MuJoCo model.

    The constants come from the model (body offsets, hinge axes, site offsets, ranges), so
    FK here equals MuJoCo's (tested). A pose is (root position (T, 3), root rotation
    (T, 3, 3), 28 hinge angles (T, 28)); a step is D = 34 numbers: root translation (3),
    root rotation vector in the world frame (3), hinge angles (28).

    Attributes:
        parents: (15,) parent of each body (index into BODY_NAMES; -1 for the pelvis).
        offsets: (15, 3) body origin in its parent's frame.
        rest: (15, 3, 3) body rotation in its parent's frame at qpos0 (identity for the boxer).
        hinge_body: (28,) body each hinge moves.
        hinge_axis: (28, 3) hinge axes in their body's frame.
        ranges: (28, 2) hinge limits, radians.
        site_body: (S,) body of each site (SITE_NAMES order).
        site_offset: (S, 3) site positions in their body's frame.
        moves: (S, 28) bool, hinge k moves site s.
    """

    parents: np.ndarray
    offsets: np.ndarray
    rest: np.ndarray
    hinge_body: np.ndarray
    hinge_axis: np.ndarray
    ranges: np.ndarray
    site_body: np.ndarray
    site_offset: np.ndarray
    moves: np.ndarray

    @classmethod
    def from_model(cls, model: mujoco.MjModel, *, prefix: str = "") -> Skeleton:
        """Read the boxer named by `prefix` out of `model`."""
        index = humanoid_index(model, prefix=prefix)
        local = {int(b): i for i, b in enumerate(index.body_ids)}
        parents = np.array([local.get(int(model.body_parentid[b]), -1) for b in index.body_ids])
        offsets = model.body_pos[index.body_ids].copy()
        rest = quat_to_matrix(model.body_quat[index.body_ids])
        hinge_body, hinge_axis, ranges = [], [], []
        for joint in JOINT_LAYOUT:
            for hinge in joint.hinges:
                j = model.joint(prefix + hinge)
                if np.any(j.pos != 0):
                    raise ValueError(f"model joint {prefix + hinge!r} must sit at its body origin")
                hinge_body.append(local[int(j.bodyid[0])])
                hinge_axis.append(j.axis.copy())
                ranges.append(j.range.copy())
        site_body = np.array([local[int(model.site_bodyid[s])] for s in index.site_ids])
        ancestors = np.zeros((NUM_BODIES, NUM_BODIES), dtype=bool)  # [b, a]: a is b or above
        for b in range(NUM_BODIES):
            a = b
            while a >= 0:
                ancestors[b, a] = True
                a = parents[a]
        hinge_body = np.array(hinge_body)
        return cls(
            parents=parents,
            offsets=offsets,
            rest=rest,
            hinge_body=hinge_body,
            hinge_axis=np.array(hinge_axis),
            ranges=np.array(ranges),
            site_body=site_body,
            site_offset=model.site_pos[index.site_ids].copy(),
            moves=ancestors[site_body][:, hinge_body],
        )

    def forward(
        self, root_pos: np.ndarray, root_rot: np.ndarray, hinges: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Forward kinematics.

        Args:
            root_pos: (T, 3), root_rot: (T, 3, 3), hinges: (T, 28).

        Returns:
            body positions (T, 15, 3), body rotations (T, 15, 3, 3), hinge axes in the world
            (T, 28, 3), site positions (T, S, 3).
        """
        frames = len(root_pos)
        pos = np.empty((frames, NUM_BODIES, 3))
        rot = np.empty((frames, NUM_BODIES, 3, 3))
        axes = np.empty((frames, NUM_ACTUATED, 3))
        pos[:, 0] = root_pos
        rot[:, 0] = root_rot @ self.rest[0]
        for b in range(1, NUM_BODIES):
            p = self.parents[b]
            pos[:, b] = pos[:, p] + rot[:, p] @ self.offsets[b]
            r = rot[:, p] @ self.rest[b]
            for k in np.flatnonzero(self.hinge_body == b):
                axes[:, k] = r @ self.hinge_axis[k]
                r = r @ axis_angle_matrix(self.hinge_axis[k], hinges[:, k])
            rot[:, b] = r
        sites = pos[:, self.site_body] + np.einsum(
            "tsij,sj->tsi", rot[:, self.site_body], self.site_offset
        )
        return pos, rot, axes, sites

    def jacobian(
        self,
        root_pos: np.ndarray,
        body_pos: np.ndarray,
        axes: np.ndarray,
        sites: np.ndarray,
        site_index: np.ndarray,
    ) -> np.ndarray:
        """Geometric Jacobian of site positions with respect to the D = 34 step coordinates.

        d p_s / d root translation = I; d p_s / d root rotation vector w = -[p_s - root]_x;
        d p_s / d hinge k = a_k x (p_s - o_k) when hinge k moves site s (a_k its world axis,
        o_k its body's origin), else 0.

        Args:
            root_pos: (T, 3); body_pos: (T, 15, 3); axes: (T, 28, 3) from `forward`.
            sites: (T, S', 3) positions of the sites `site_index` (S',) picks.

        Returns:
            (T, S', 3, 34).
        """
        frames, count = sites.shape[:2]
        jac = np.zeros((frames, count, 3, 6 + NUM_ACTUATED))
        jac[..., :3] = np.eye(3)
        d = sites - root_pos[:, None]
        zero = np.zeros(d.shape[:-1])
        jac[..., 3:6] = -np.stack(
            [
                np.stack([zero, -d[..., 2], d[..., 1]], -1),
                np.stack([d[..., 2], zero, -d[..., 0]], -1),
                np.stack([-d[..., 1], d[..., 0], zero], -1),
            ],
            axis=-2,
        )
        anchors = body_pos[:, self.hinge_body]  # (T, 28, 3)
        lever = sites[:, :, None, :] - anchors[:, None, :, :]  # (T, S', 28, 3)
        columns = np.cross(axes[:, None], lever) * self.moves[site_index][None, :, :, None]
        jac[..., 6:] = np.swapaxes(columns, -1, -2)
        return jac


def qpos_to_pose(qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(T, 35) qpos to (root position (T, 3), root rotation (T, 3, 3), hinges (T, 28))."""
    return qpos[:, ROOT_POS].copy(), quat_to_matrix(qpos[:, ROOT_QUAT]), qpos[:, 7:].copy()


def pose_to_qpos(root_pos: np.ndarray, root_rot: np.ndarray, hinges: np.ndarray) -> np.ndarray:
    """Inverse of `qpos_to_pose`: (T, 35) qpos."""
    return np.concatenate([root_pos, matrix_to_quat(root_rot), hinges], axis=1)


def wrap_to_ranges(hinges: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """Hinge angles moved by a whole turn where that brings them nearer their range, then
    clipped into it.

    Args:
        hinges: (T, 28) radians.
        ranges: (28, 2) limits (radians).

    Returns:
        (T, 28) angles within `ranges`.
    """
    lo, hi = ranges[:, 0], ranges[:, 1]
    candidates = hinges[..., None] + np.array([-2 * np.pi, 0.0, 2 * np.pi])
    outside = np.maximum(lo[:, None] - candidates, 0) + np.maximum(candidates - hi[:, None], 0)
    best = np.take_along_axis(candidates, outside.argmin(-1)[..., None], -1)[..., 0]
    return np.clip(best, lo, hi)


def _rotation_step(root_rot: np.ndarray, rotvec: np.ndarray) -> np.ndarray:
    """exp([w]_x) @ root_rot for (T, 3) rotation vectors w in the world frame."""
    angle = np.linalg.norm(rotvec, axis=-1)
    axis = rotvec / np.maximum(angle, 1e-12)[:, None]
    k = np.zeros((len(rotvec), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    k = k - np.swapaxes(k, 1, 2)
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    step = np.eye(3) + s * k + (1 - c) * (k @ k)
    out = step @ root_rot
    u, _, vt = np.linalg.svd(out)  # re-orthonormalise
    return u @ vt


def solve_ik(
    skeleton: Skeleton,
    qpos: np.ndarray,
    site_index: np.ndarray,
    targets: np.ndarray,
    weights: np.ndarray,
    *,
    dofs: np.ndarray,
    iterations: int,
    damping: float,
) -> np.ndarray:
    """Batched Levenberg-Marquardt IK: move sites onto targets, hinges kept in their ranges.

    Minimises sum_s w_ts^2 |p_s(q_t) - target_ts|^2 for every frame t at once, over the step
    coordinates `dofs` (of the D = 34: 0-2 root translation, 3-5 root rotation, 6+ hinges).
    Each iteration solves (J^T W J + lambda diag(J^T W J) + eps I) dq = -J^T W r per frame;
    hinges the step would push past a limit are set onto it and held there while the others
    are solved (one active-set pass). lambda is adapted per frame: a step that raises the
    cost is refused and lambda grows 10x; an accepted one divides it by 3.

    Args:
        skeleton: the humanoid's kinematics.
        qpos: (T, 35) start poses (hinges within their ranges).
        site_index: (S',) sites (SITE_NAMES order) with targets.
        targets: (T, S', 3) target positions, metres.
        weights: (T, S') residual weights (0 leaves a site out of a frame).
        dofs: (D',) step coordinates that move.
        iterations: LM iterations.
        damping: the initial lambda.

    Returns:
        (T, 35) fitted qpos.
    """
    root_pos, root_rot, hinges = qpos_to_pose(qpos)
    frames = len(qpos)
    dofs = np.asarray(dofs)
    is_hinge = dofs >= 6
    hinge_of = np.where(is_hinge, dofs - 6, 0)
    lo = np.where(is_hinge, skeleton.ranges[hinge_of, 0], -np.inf)
    hi = np.where(is_hinge, skeleton.ranges[hinge_of, 1], np.inf)
    w2 = weights**2

    def cost_and_parts(rp, rr, hg):
        body_pos, _, axes, sites = skeleton.forward(rp, rr, hg)
        sites = sites[:, site_index]
        residual = sites - targets
        cost = (w2 * (residual**2).sum(-1)).sum(-1)
        return cost, body_pos, axes, sites, residual

    cost, body_pos, axes, sites, residual = cost_and_parts(root_pos, root_rot, hinges)
    lam = np.full(frames, damping)
    eye = np.eye(len(dofs))
    for _ in range(iterations):
        jac = skeleton.jacobian(root_pos, body_pos, axes, sites, site_index)[..., dofs]
        normal = np.einsum("tsik,ts,tsil->tkl", jac, w2, jac)
        gradient = np.einsum("tsik,ts,tsi->tk", jac, w2, residual)
        diagonal = np.diagonal(normal, axis1=1, axis2=2)
        system = normal + (lam[:, None] * diagonal + 1e-9)[:, :, None] * eye
        step = np.linalg.solve(system, -gradient[..., None])[..., 0]
        # Active set: hinges pushed past a limit go onto it and stay; the rest re-solved.
        current = np.where(is_hinge, hinges[:, hinge_of], 0.0)
        clamped = np.clip(current + step, lo, hi)
        held = clamped != current + step
        if held.any():
            fixed = np.where(held, clamped - current, 0.0)
            rhs = -gradient - np.einsum("tkl,tl->tk", system, fixed)
            free_pair = ~held[:, :, None] & ~held[:, None, :]
            system = np.where(free_pair, system, 0.0) + held[:, :, None] * eye
            rhs = np.where(held, fixed, rhs)
            step = np.linalg.solve(system, rhs[..., None])[..., 0]
            step = np.clip(current + np.where(held, fixed, step), lo, hi) - current
        full = np.zeros((frames, 6 + NUM_ACTUATED))
        full[:, dofs] = step
        new_pos = root_pos + full[:, :3]
        new_rot = _rotation_step(root_rot, full[:, 3:6])
        new_hinges = np.clip(hinges + full[:, 6:], skeleton.ranges[:, 0], skeleton.ranges[:, 1])
        new = cost_and_parts(new_pos, new_rot, new_hinges)
        better = new[0] <= cost
        lam = np.where(better, lam / 3.0, lam * 10.0)
        pick = better[:, None]
        root_pos = np.where(pick, new_pos, root_pos)
        root_rot = np.where(pick[:, :, None], new_rot, root_rot)
        hinges = np.where(pick, new_hinges, hinges)
        cost = np.where(better, new[0], cost)
        body_pos = np.where(pick[:, :, None], new[1], body_pos)
        axes = np.where(pick[:, :, None], new[2], axes)
        sites = np.where(pick[:, :, None], new[3], sites)
        residual = np.where(pick[:, :, None], new[4], residual)
    return pose_to_qpos(root_pos, root_rot, hinges)


# ---------------------------------------------------------------------------------------------
# Fit the humanoid


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _perpendicular(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The part of `v` perpendicular to the unit `axis`, both (..., 3)."""
    return v - (v * axis).sum(-1, keepdims=True) * axis


def _frame(first: str, a: np.ndarray, second: str, b: np.ndarray) -> np.ndarray:
    """A rotation whose axis `first` points along `a` and axis `second` as near `b` as it can
    (Gram-Schmidt); axes named "x", "y", "z"; returns (..., 3, 3) with the axes as columns."""
    axes = {first: _unit(a)}
    axes[second] = _unit(_perpendicular(b, axes[first]))
    third = ({"x", "y", "z"} - {first, second}).pop()
    cyclic = {"x": ("y", "z"), "y": ("z", "x"), "z": ("x", "y")}[third]
    axes[third] = np.cross(axes[cyclic[0]], axes[cyclic[1]])
    return np.stack([axes["x"], axes["y"], axes["z"]], axis=-1)


def body_rotations_from_points(points: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """A first guess of the 15 body rotations from BlazePose-order world joints.

    The pelvis stands upright, turned so its y axis runs along the hips (right to left);
    the torso's z axis runs from the abdomen joint to the mid-shoulder point, its y axis
    along the shoulders; the head's y axis along the ears, its x axis towards the nose. A
    limb segment's z axis points from its far joint back to its near one (the limbs hang
    along -z at rest); its bending axis comes from the next segment's direction (forearms
    bend towards the upper arm's +x, shins towards the thigh's -x), with the parent's
    forward axis as a weak fallback for a straight limb. Feet: x from heel to toe, z from
    the sole up to the ankle. Hands follow their forearms.

    Args:
        points: (T, 33, 3) finite world joints, metres.
        skeleton: the humanoid (for the abdomen joint's offset).

    Returns:
        (T, 15, 3, 3) world rotations, BODY_NAMES order.
    """

    def at(name: str) -> np.ndarray:
        return points[:, _k(name)]

    rot = np.empty((len(points), NUM_BODIES, 3, 3))
    body = {name: i for i, name in enumerate(BODY_NAMES)}
    up = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (len(points), 3))
    hips = at("left_hip") - at("right_hip")
    rot[:, body["pelvis"]] = _frame("y", hips, "z", up)
    pelvis = rot[:, body["pelvis"]]
    mid_hip = (at("left_hip") + at("right_hip")) / 2
    abdomen = mid_hip + pelvis @ skeleton.offsets[body["torso"]]
    mid_shoulder = (at("left_shoulder") + at("right_shoulder")) / 2
    rot[:, body["torso"]] = _frame(
        "y", at("left_shoulder") - at("right_shoulder"), "z", mid_shoulder - abdomen
    )
    torso = rot[:, body["torso"]]
    mid_ear = (at("left_ear") + at("right_ear")) / 2
    rot[:, body["head"]] = _frame("y", at("left_ear") - at("right_ear"), "x", at("nose") - mid_ear)

    def limb(upper: str, lower: str, near: str, joint: str, far: str, sign: float, parent):
        direction = at(joint) - at(near)
        z = -_unit(direction)
        bend = sign * _perpendicular(at(far) - at(joint), z)
        fallback = _perpendicular(parent[..., 0], z)  # the parent's forward axis
        length = np.linalg.norm(at(far) - at(joint), axis=-1, keepdims=True)
        rot[:, body[upper]] = _frame("z", z, "x", bend + 0.05 * length * _unit(fallback))
        hinge_y = rot[:, body[upper]][..., 1]
        rot[:, body[lower]] = _frame("z", at(joint) - at(far), "y", hinge_y)

    for side in ("right", "left"):
        limb(f"{side}_upper_arm", f"{side}_lower_arm", f"{side}_shoulder", f"{side}_elbow",
             f"{side}_wrist", 1.0, torso)  # fmt: skip
        rot[:, body[f"{side}_hand"]] = rot[:, body[f"{side}_lower_arm"]]
        limb(f"{side}_thigh", f"{side}_shin", f"{side}_hip", f"{side}_knee", f"{side}_ankle",
             -1.0, pelvis)  # fmt: skip
        heel, toe, ankle = at(f"{side}_heel"), at(f"{side}_foot_index"), at(f"{side}_ankle")
        rot[:, body[f"{side}_foot"]] = _frame("x", toe - heel, "z", ankle - heel)
    return rot


def site_targets(points: np.ndarray, face_weight: float) -> tuple[np.ndarray, np.ndarray]:
    """Each humanoid site's target: the mean of the BlazePose landmarks it stands for.

    Args:
        points: (T, 33, 3) world joints.
        face_weight: weight of the head's sites; the others weigh 1.

    Returns:
        targets (T, S, 3) and weights (S,), SITE_NAMES order (sites no landmark maps to
        get weight 0).
    """
    targets = np.zeros((len(points), len(SITE_NAMES), 3))
    weights = np.zeros(len(SITE_NAMES))
    for s, site in enumerate(SITE_NAMES):
        members = [j for j, name in enumerate(BLAZEPOSE_33) if BLAZEPOSE_TO_SITE[name] == site]
        if members:
            targets[:, s] = points[:, members].mean(1)
            weights[s] = face_weight if site in _FACE_SITES else 1.0
    return targets, weights


def fit_humanoid(
    points: np.ndarray,
    bones: BoneLengths,
    *,
    config: LiftConfig = LiftConfig(),  # noqa: B008 (frozen, so a safe default)
) -> np.ndarray:
    """Inverse kinematics of the boxer humanoid (built with `bones`) to 3D joints.

    Every frame at once: `body_rotations_from_points` gives a first pose (hinges wrapped and
    clipped into their ranges), then `solve_ik` moves all 34 degrees of freedom so the sites
    meet the landmarks they stand for (`site_targets`), within the joint limits.

    Args:
        points: (T, 33, 3) BlazePose-order world joints, metres, finite.
        bones: the fighter's segment lengths (the humanoid is built from them).
        config: IK iterations, damping and face weight.

    Returns:
        (T, 35) qpos, hinges within their ranges.
    """
    p = _array("points", points, (None, NUM_KEYPOINTS, 3))
    if len(p) == 0 or not np.isfinite(p).all():
        raise ValueError("points must hold at least one frame and be finite")
    if not isinstance(bones, BoneLengths):
        raise TypeError(f"bones must be a BoneLengths, got {type(bones).__name__}")
    skeleton = Skeleton.from_model(mujoco.MjModel.from_xml_string(boxer_mjcf(bones)))
    rotations = body_rotations_from_points(p, skeleton)
    root = p[:, list(HIPS)].mean(1)
    qpos = qpos_from_body_rotations(root, rotations)
    qpos[:, 7:] = wrap_to_ranges(qpos[:, 7:], skeleton.ranges)
    targets, weights = site_targets(p, config.ik_face_weight)
    used = np.flatnonzero(weights > 0)
    return solve_ik(
        skeleton,
        qpos,
        used,
        targets[:, used],
        np.broadcast_to(weights[used], (len(p), len(used))),
        dofs=np.arange(6 + NUM_ACTUATED),
        iterations=config.ik_iterations,
        damping=config.ik_damping,
    )


# ---------------------------------------------------------------------------------------------
# Cleanup: geometry of the humanoid's geoms in MuJoCo


@dataclass(frozen=True, eq=False)
class GeomPoses:
    """World poses of one humanoid's geoms over a clip, from MuJoCo's kinematics.

    Attributes:
        kind: (G,) mjtGeom types (capsule, sphere or box).
        size: (G, 3) MuJoCo geom sizes.
        pos: (T, G, 3) centres, metres.
        rot: (T, G, 3, 3) orientations.
        foot: (2, ) geom index (into G) of the left and right foot boxes.
    """

    kind: np.ndarray
    size: np.ndarray
    pos: np.ndarray
    rot: np.ndarray
    foot: tuple[int, int]


def _check_model(name: str, model: mujoco.MjModel) -> HumanoidIndex:
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"{name} must be a mujoco.MjModel, got {type(model).__name__}")
    index = humanoid_index(model)
    if model.nq != NQ or model.nv != NV:
        raise ValueError(
            f"{name} must hold one boxer and nothing else that moves (nq {NQ}, nv {NV}), "
            f"got nq {model.nq}, nv {model.nv}"
        )
    return index


def geom_poses(model: mujoco.MjModel, qpos: np.ndarray) -> GeomPoses:
    """The boxer's geoms (not the floor's) in every frame, by `mj_kinematics`.

    Args:
        model: a model holding one boxer (prefix "").
        qpos: (T, 35).
    """
    index = humanoid_index(model)
    geoms = np.flatnonzero(np.isin(model.geom_bodyid, index.body_ids))
    data = mujoco.MjData(model)
    pos = np.empty((len(qpos), len(geoms), 3))
    rot = np.empty((len(qpos), len(geoms), 3, 3))
    for frame, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        pos[frame] = data.geom_xpos[geoms]
        rot[frame] = data.geom_xmat[geoms].reshape(-1, 3, 3)
    names = [model.geom(int(g)).name for g in geoms]
    return GeomPoses(
        kind=model.geom_type[geoms].copy(),
        size=model.geom_size[geoms].copy(),
        pos=pos,
        rot=rot,
        foot=(names.index("left_foot"), names.index("right_foot")),
    )


_BOX_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)


def lowest_points(poses: GeomPoses) -> np.ndarray:
    """Height of each geom's lowest point: (T, G) metres.

    Spheres: centre z - radius; capsules: the lower end's z - radius; boxes: the lowest of
    the 8 corners.
    """
    z = poses.pos[..., 2]
    radius = poses.size[:, 0]
    reach = np.zeros_like(z)
    capsule = poses.kind == mujoco.mjtGeom.mjGEOM_CAPSULE
    box = poses.kind == mujoco.mjtGeom.mjGEOM_BOX
    # Capsule: half-length size[1] along the geom's z axis.
    reach = np.where(capsule, np.abs(poses.rot[..., 2, 2]) * poses.size[:, 1], reach)
    corner_z = np.einsum("tgj,gcj->tgc", poses.rot[..., 2, :], _BOX_CORNERS * poses.size[:, None])
    low = z - reach - np.where(box, 0.0, radius)
    return np.where(box, z + corner_z.min(-1), low)


def floor_depth(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """How deep the boxer sinks into the floor (z = 0) in each frame: (T,) metres, the deepest
    geom's lowest point below the floor, 0 where every geom is at or above it.

    Args:
        model: a model holding one boxer (prefix "").
        qpos: (T, 35).
    """
    return np.maximum(-lowest_points(geom_poses(model, qpos)).min(1), 0.0)


def _foot_lowest(poses: GeomPoses) -> np.ndarray:
    """(T, 2) lowest point of the left and right foot boxes."""
    return lowest_points(poses)[:, list(poses.foot)]


def capsules(poses: GeomPoses) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The geoms as capsules: segment ends (T, C, 3) twice and radii (C,), C >= G.

    A capsule stays itself and a sphere is a zero-length capsule. A box becomes capsules
    along its longest axis with its smallest half-size as radius, side by side along its
    middle axis, enough of them to span it (the feet: two sole-thick rods from heel to toe);
    they lie inside the box and miss only its edges and corners (by at most 0.3 radius).
    """
    starts, ends, radii, geoms = [], [], [], []
    for g, (kind, size) in enumerate(zip(poses.kind, poses.size, strict=True)):
        if kind == mujoco.mjtGeom.mjGEOM_BOX:
            order = np.argsort(size)  # smallest, middle, longest half-size
            radius, middle, longest = size[order]
            count = max(1, math.ceil(middle / radius - 1e-9))
            along = np.zeros(3)
            along[order[2]] = longest - radius
            for offset in np.linspace(-(middle - radius), middle - radius, count):
                side = np.zeros(3)
                side[order[1]] = offset
                starts.append(side - along)
                ends.append(side + along)
                radii.append(radius)
                geoms.append(g)
        else:
            half = size[1] if kind == mujoco.mjtGeom.mjGEOM_CAPSULE else 0.0
            starts.append(np.array([0.0, 0.0, -half]))
            ends.append(np.array([0.0, 0.0, half]))
            radii.append(size[0])
            geoms.append(g)
    geoms = np.array(geoms)
    rot, pos = poses.rot[:, geoms], poses.pos[:, geoms]
    a = pos + np.einsum("tcij,cj->tci", rot, np.array(starts))
    b = pos + np.einsum("tcij,cj->tci", rot, np.array(ends))
    return a, b, np.array(radii)


def segment_distances(
    p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points of segments [p1, q1] and [p2, q2], broadcast over leading dimensions.

    Ericson, "Real-Time Collision Detection", 2005, §5.1.9 (ClosestPtSegmentSegment), with
    degenerate (point) segments handled.

    Returns:
        distance (...), closest point on the first (..., 3) and on the second (..., 3).
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = (d1 * d1).sum(-1)
    e = (d2 * d2).sum(-1)
    f = (d2 * r).sum(-1)
    c = (d1 * r).sum(-1)
    b = (d1 * d2).sum(-1)
    eps = 1e-12
    safe_a, safe_e = np.maximum(a, eps), np.maximum(e, eps)
    denom = a * e - b * b
    # General case: the lines' closest s, clamped; then t, and s again if t was clamped.
    s = np.where(denom > eps, np.clip((b * f - c * e) / np.maximum(denom, eps), 0, 1), 0.0)
    t = (b * s + f) / safe_e
    s = np.where(t < 0, np.clip(-c / safe_a, 0, 1), s)
    s = np.where(t > 1, np.clip((b - c) / safe_a, 0, 1), s)
    t = np.clip(t, 0, 1)
    # The second segment is a point: t = 0, s the first's closest to it.
    s = np.where(e <= eps, np.clip(-c / safe_a, 0, 1), s)
    t = np.where(e <= eps, 0.0, t)
    # The first segment is a point: s = 0, t the second's closest to it.
    t = np.where(a <= eps, np.where(e <= eps, 0.0, np.clip(f / safe_e, 0, 1)), t)
    s = np.where(a <= eps, 0.0, s)
    c1 = p1 + s[..., None] * d1
    c2 = p2 + t[..., None] * d2
    return np.linalg.norm(c1 - c2, axis=-1), c1, c2


def interpenetration(
    poses: GeomPoses, other: GeomPoses, offset: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """How deep two fighters' geoms (as `capsules`) go into each other, per frame.

    Args:
        poses, other: the two fighters' geoms over the same T frames.
        offset: (T, 3) translation added to the first fighter's geoms, or None.

    Returns:
        depth (T, C1, C2) metres (negative: apart by that much) and unit normals
        (T, C1, C2, 3) pointing from the second fighter's capsule towards the first's, over
        the `capsules` of each.
    """
    a1, b1, r1 = capsules(poses)
    a2, b2, r2 = capsules(other)
    if offset is not None:
        a1, b1 = a1 + offset[:, None], b1 + offset[:, None]
    dist, c1, c2 = segment_distances(a1[:, :, None], b1[:, :, None], a2[:, None, :], b2[:, None, :])
    normal = (c1 - c2) / np.maximum(dist, 1e-9)[..., None]
    return r1[:, None] + r2[None, :] - dist, normal


# ---------------------------------------------------------------------------------------------
# Cleanup steps


def smooth_qpos(qpos: np.ndarray, sigma: float, ranges: np.ndarray) -> np.ndarray:
    """`gaussian_smooth` of a humanoid motion: root position, root quaternion (signs aligned
    with the previous frame, renormalised) and unwrapped hinge angles (clipped to `ranges`)."""
    out = qpos.copy()
    if sigma <= 0 or len(qpos) < 3:
        return out
    out[:, ROOT_POS] = gaussian_smooth(qpos[:, ROOT_POS], sigma)
    quat = qpos[:, ROOT_QUAT].copy()
    for frame in range(1, len(quat)):
        if quat[frame] @ quat[frame - 1] < 0:
            quat[frame] = -quat[frame]
    quat = gaussian_smooth(quat, sigma)
    out[:, ROOT_QUAT] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    hinges = gaussian_smooth(np.unwrap(qpos[:, 7:], axis=0), sigma)
    out[:, 7:] = wrap_to_ranges(hinges, ranges)
    return out


def _blend_corrections(values: np.ndarray, active: np.ndarray, blend: int) -> np.ndarray:
    """Spread per-frame corrections from `active` frames to their neighbours.

    Between two active runs the correction is interpolated linearly; it fades out over
    `blend` frames (raised cosine) after a run and fades in before one, and is 0 further
    away.

    Args:
        values: (T, D) corrections, used where `active`.
        active: (T,) bool.
        blend: fade length in frames.

    Returns:
        (T, D) corrections, equal to `values` on active frames.
    """
    frames = len(values)
    out = np.zeros_like(values)
    if not active.any():
        return out
    index = np.flatnonzero(active)
    timeline = np.arange(frames)
    for d in range(values.shape[1]):
        out[:, d] = np.interp(timeline, index, values[index, d])
    previous = np.maximum.accumulate(np.where(active, timeline, -(10**9)))
    following = np.minimum.accumulate(np.where(active, timeline, 10**9)[::-1])[::-1]
    distance = np.minimum(timeline - previous, following - timeline).astype(float)
    fade = np.where(
        distance <= 0,
        1.0,
        np.where(distance > blend, 0.0, 0.5 * (1 + np.cos(np.pi * distance / (blend + 1)))),
    )
    return out * fade[:, None]


_FOOT_SITES = {
    side: np.array([SITE_NAMES.index(f"{side}_{s}") for s in ("ankle", "heel", "foot_index")])
    for side in ("left", "right")
}


def _leg_dofs(side: str) -> np.ndarray:
    dofs = []
    for joint in JOINT_LAYOUT:
        if joint.name in (f"{side}_hip", f"{side}_knee", f"{side}_ankle"):
            dofs.extend(range(joint.qpos_start - 1, joint.qpos_start - 1 + joint.dofs))
    return np.array(dofs)


def _foot_shifts(
    model: mujoco.MjModel, skeleton: Skeleton, qpos: np.ndarray, contacts: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each contact foot should go: the translation onto its anchor and the floor.

    A foot's anchor for one contact run is the mean horizontal position of its sole midpoint
    (between the heel and toe sites) over the run; the translation moves the midpoint onto it
    and the foot box's lowest corner onto z = 0.

    Returns:
        shifts (T, 2, 3) (zero outside contact), site positions (T, S, 3) and the feet's
        lowest points (T, 2), for left and right.
    """
    _, _, _, sites = skeleton.forward(*qpos_to_pose(qpos))
    low = _foot_lowest(geom_poses(model, qpos))
    shifts = np.zeros((len(qpos), 2, 3))
    for f, side in enumerate(("left", "right")):
        heel, toe = _FOOT_SITES[side][1:]
        middle = (sites[:, heel, :2] + sites[:, toe, :2]) / 2
        for start, stop in _runs(contacts[:, f]):
            shifts[start:stop, f, :2] = middle[start:stop].mean(0) - middle[start:stop]
            shifts[start:stop, f, 2] = -low[start:stop, f]
    return shifts, sites, low


def _follow_feet(
    model: mujoco.MjModel,
    skeleton: Skeleton,
    qpos: np.ndarray,
    contacts: np.ndarray,
    config: LiftConfig,
) -> np.ndarray:
    """Step 1 of `fix_feet`: the root moves (smoothly) as the contact feet should."""
    out = qpos.copy()
    shifts, _, _ = _foot_shifts(model, skeleton, out, contacts)
    any_contact = contacts.any(1)
    count = np.maximum(contacts.sum(1), 1)[:, None]
    root_shift = np.zeros((len(out), 3))
    root_shift[:, :2] = (shifts[..., :2] * contacts[..., None]).sum(1) / count
    root_shift[:, 2] = np.where(contacts, shifts[..., 2], -np.inf).max(1)
    frames = np.arange(len(out))
    for d in range(3):
        root_shift[:, d] = np.interp(frames, frames[any_contact], root_shift[any_contact, d])
    out[:, :3] += gaussian_smooth(root_shift, config.root_follow_sigma_frames)
    return out


def fix_feet(
    model: mujoco.MjModel,
    skeleton: Skeleton,
    qpos: np.ndarray,
    contacts: np.ndarray,
    config: LiftConfig,
    *,
    follow: bool = True,
) -> np.ndarray:
    """Feet on the floor without skating while in contact, mostly by moving the whole body.

    1. The root follows the contact feet: per contact frame, horizontally by the mean of the
       contact feet's `_foot_shifts`, vertically by what brings the lower contact foot to the
       floor; interpolated between contact frames and smoothed (Gaussian,
       `config.root_follow_sigma_frames`). A lift's error is largely a rigid slip of the
       whole body (its depth), which this takes out without bending the legs.
    2. The shifts left after that (anchors recomputed) fade in and out over
       `config.contact_blend_frames` around each run (`_blend_corrections`) and never leave
       a foot below the floor; leg IK (`solve_ik` on both hips, knees and ankles, the three
       foot sites each) moves the feet by them, orientation kept.

    Args:
        model, skeleton: the boxer.
        qpos: (T, 35).
        contacts: (T, 2) bool, left and right.
        config: the settings.
        follow: False skips step 1 (the root stays; only the legs move).

    Returns:
        (T, 35) corrected qpos.
    """
    out = qpos.copy()
    if not contacts.any():
        return out
    if follow:
        out = _follow_feet(model, skeleton, out, contacts, config)
    shifts, sites, low = _foot_shifts(model, skeleton, out, contacts)
    site_index, targets, dofs = [], [], []
    for f, side in enumerate(("left", "right")):
        shift = _blend_corrections(shifts[:, f], contacts[:, f], config.contact_blend_frames)
        shift[:, 2] = np.maximum(shift[:, 2], -low[:, f])  # never below the floor
        site_index.append(_FOOT_SITES[side])
        targets.append(sites[:, _FOOT_SITES[side]] + shift[:, None])
        dofs.append(_leg_dofs(side))
    site_index = np.concatenate(site_index)
    return solve_ik(
        skeleton,
        out,
        site_index,
        np.concatenate(targets, axis=1),
        np.ones((len(out), len(site_index))),
        dofs=np.concatenate(dofs),
        iterations=config.cleanup_ik_iterations,
        damping=config.ik_damping,
    )


def separation_offsets(
    poses: GeomPoses,
    other: GeomPoses,
    root: np.ndarray,
    other_root: np.ndarray,
    config: LiftConfig,
    *,
    iterations: int = 16,
    reach: float = 2.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal root offsets that end two fighters' overlap, minimally and smoothly.

    The fighters move apart along the horizontal line between their roots (u, from the
    other to this one). Per frame, bisection finds the least separation s_t (up to `reach`)
    after which no pair of geoms (`interpenetration`) is closer than
    `config.separation_margin_m`; s is then made smooth by `_max_then_mean` (still >= every
    frame's need). This fighter moves by `config.separation_share` of s, the other by the
    rest.

    Args:
        poses, other: the two fighters' geoms over the same frames.
        root, other_root: (T, 3) their root positions.
        config: margin, share and smoothing.
        iterations: bisection steps (the last one's bracket is reach / 2^iterations).
        reach: the largest separation tried, metres.

    Returns:
        (T, 3) offsets for this fighter and (T, 3) for the other (zero z).
    """
    line = root[:, :2] - other_root[:, :2]
    length = np.linalg.norm(line, axis=1, keepdims=True)
    u2 = np.where(length > 1e-6, line / np.maximum(length, 1e-9), np.array([1.0, 0.0]))
    u = np.concatenate([u2, np.zeros((len(u2), 1))], axis=1)

    def clear(separation: np.ndarray) -> np.ndarray:
        depth, _ = interpenetration(poses, other, separation[:, None] * u)
        return depth.max(axis=(1, 2)) <= -config.separation_margin_m

    low = np.zeros(len(u))
    high = np.where(clear(low), 0.0, reach)
    for _ in range(iterations):
        middle = (low + high) / 2
        ok = clear(middle)
        high = np.where(ok, middle, high)
        low = np.where(ok, low, middle)
    need = _max_then_mean(high, config.separation_smooth_frames)
    share = config.separation_share
    return share * need[:, None] * u, -(1 - share) * need[:, None] * u


def _separate(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    other: GeomPoses,
    other_qpos: np.ndarray,
    other_shift: np.ndarray,
    config: LiftConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """`separation_offsets` against the other fighter as moved by `other_shift` so far;
    returns this fighter's moved qpos and the other's total assumed shift."""
    shifted = GeomPoses(other.kind, other.size, other.pos + other_shift[:, None], other.rot,
                        other.foot)  # fmt: skip
    mine, theirs = separation_offsets(
        geom_poses(model, qpos),
        shifted,
        qpos[:, :3],
        other_qpos[:, :3] + other_shift,
        config,
    )
    out = qpos.copy()
    out[:, :3] += mine
    return out, other_shift + theirs


def lift_above_floor(model: mujoco.MjModel, qpos: np.ndarray, half: int) -> np.ndarray:
    """Raise the root by the least smooth amount (`_max_then_mean`) that puts every geom's
    lowest point at or above the floor in every frame."""
    out = qpos.copy()
    depth = floor_depth(model, out)
    if depth.max() > 0:
        out[:, 2] += _max_then_mean(depth, half)
    return out


def settle_on_floor(
    model: mujoco.MjModel, qpos: np.ndarray, half: int
) -> tuple[np.ndarray, np.ndarray]:
    """Lower a fighter who floats onto the floor: nobody stands in the air for long.

    The root comes down by a smooth lower envelope of the lowest geom's height (a running min
    then a running mean over 2 half + 1 frames, the mirror of `_max_then_mean`), so a hop
    shorter than the window keeps its flight and no frame goes below the floor for it.

    Returns the lowered qpos and the drop per frame (T,), metres (>= 0); half 0 lowers nothing.
    """
    if half <= 0:
        return qpos.copy(), np.zeros(len(qpos))
    clearance = np.maximum(lowest_points(geom_poses(model, qpos)).min(1), 0.0)
    drop = -_max_then_mean(-clearance, half)
    out = qpos.copy()
    out[:, 2] -= drop
    return out, drop


def sole_positions(skeleton: Skeleton, qpos: np.ndarray) -> np.ndarray:
    """(T, 2, 3) midpoint of each foot's heel and toe sites (left, right)."""
    _, _, _, sites = skeleton.forward(*qpos_to_pose(qpos))
    return np.stack(
        [
            (sites[:, _FOOT_SITES[s][1]] + sites[:, _FOOT_SITES[s][2]]) / 2
            for s in ("left", "right")
        ],
        axis=1,
    )


def contact_slide(soles: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """How far each foot slides along the floor while in contact, frame to frame.

    Args:
        soles: (T, 2, 3) sole points of the left and right foot (`sole_positions`), metres.
        contacts: (T, 2) bool, each foot in contact.

    Returns:
        (T - 1, 2) horizontal distance in metres from frame t to t + 1 of each foot in
        contact in both frames; NaN for the others (a foot in the air does not skate).
    """
    both = contacts[1:] & contacts[:-1]
    slide = np.linalg.norm(soles[1:, :, :2] - soles[:-1, :, :2], axis=-1)
    return np.where(both, slide, np.nan)


def _motion_metrics(
    model: mujoco.MjModel,
    skeleton: Skeleton,
    qpos: np.ndarray,
    contacts: np.ndarray,
    fps: float,
) -> dict[str, float]:
    """The plausibility numbers `Cleaned.metrics` reports for one motion."""
    points = keypoint_positions(model, qpos)
    soles = sole_positions(skeleton, qpos)
    slide = contact_slide(soles, contacts)
    return {
        "floor_penetration_mm": float(floor_depth(model, qpos).max() * 1000),
        "foot_height_cm": float(np.median(_foot_lowest(geom_poses(model, qpos)).min(1)) * 100),
        "foot_skating_cm_per_frame": (foot_skating_cm_per_frame(soles) if len(qpos) >= 2 else 0.0),
        "contact_slide_cm_per_frame": (
            float(np.nanmean(slide) * 100) if np.isfinite(slide).any() else 0.0
        ),
        "jitter_m_s2": jitter_m_s2(points, fps) if len(qpos) >= 3 else 0.0,
    }


def cleanup(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    contacts: np.ndarray,
    *,
    fps: float,
    config: LiftConfig = LiftConfig(),  # noqa: B008 (frozen, so a safe default)
    other_qpos: np.ndarray | None = None,
    other_model: mujoco.MjModel | None = None,
) -> Cleaned:
    """Remove from one fighter's humanoid motion what a body cannot do.

    In order:
    1. jitter: `smooth_qpos`, hinges kept in their ranges; a fighter floating above the floor
       for longer than `config.floor_settle_s` lowered onto it (`settle_on_floor`);
    2. contacts: `contacts` joined with those MuJoCo's foot geoms show (lowest box corner
       below `config.contact_height_m`, sole slower than `config.contact_speed_m_s`),
       cleaned of short runs (`clean_runs`);
    3. with another fighter, its overlap pushed out (`separation_offsets`; this fighter makes
       `config.separation_share` of it and assumes the other makes the rest);
    4. feet on the floor without skating (`fix_feet`);
    5. with another fighter, what overlap step 4 brought back pushed out again, the contact
       feet pinned again by the legs alone, and a last push;
    6. any geom still below the floor lifted (`lift_above_floor`), qvel (`velocities`).

    The other fighter is taken as given (`other_qpos`), so the overlap is gone exactly when
    its final motion is passed with `separation_share` = 1; `cleanup_pair` does that.

    Args:
        model: a compiled model with one boxer (prefix "") and nothing else that moves, e.g.
            `single_scene_mjcf(bones)`; nq must be 35.
        qpos: (T, 35) its motion (e.g. `fit_humanoid`'s).
        contacts: (T, 2) bool, left and right foot in contact (e.g. `Lifted3D.contacts`).
        fps: frames per second.
        config: the settings.
        other_qpos: (T, 35) the other fighter's motion in the same world, or None.
        other_model: the other fighter's model (its bones); None uses `model`.

    Returns:
        `Cleaned` with qpos, qvel, the humanoid's BlazePose-order points, the contacts used
        and before/after metrics.

    Raises:
        ValueError: naming the argument whose shape or values are wrong.
    """
    _check_model("model", model)
    q = _array("qpos", qpos, (None, NQ))
    frames = len(q)
    if frames == 0 or not np.isfinite(q).all():
        raise ValueError("qpos must hold at least one frame and be finite")
    c = np.asarray(contacts)
    if c.shape != (frames, 2) or c.dtype != bool:
        raise ValueError(f"contacts must be a (T, 2) = ({frames}, 2) bool array, got {c.shape} "
                         f"{c.dtype}")  # fmt: skip
    fps = _check_fps(fps)
    if other_qpos is not None:
        other_model = model if other_model is None else other_model
        _check_model("other_model", other_model)
        other_q = _array("other_qpos", other_qpos, (frames, NQ))
        if not np.isfinite(other_q).all():
            raise ValueError("other_qpos must be finite")

    skeleton = Skeleton.from_model(model)
    out = smooth_qpos(q, config.smooth_sigma_frames, skeleton.ranges)
    out[:, 7:] = np.clip(out[:, 7:], skeleton.ranges[:, 0], skeleton.ranges[:, 1])
    out, drop = settle_on_floor(model, out, round(config.floor_settle_s * fps / 2))
    poses = geom_poses(model, out)
    soles = sole_positions(skeleton, out)
    speed = horizontal_speed(soles, fps)
    seen = (_foot_lowest(poses) < config.contact_height_m) & (speed < config.contact_speed_m_s)
    used = clean_runs(c | seen, config.contact_min_frames)
    # Measured at the floor: a floating foot's skating weighs nothing, which would flatter it.
    settled = q.copy()
    settled[:, 2] -= drop
    before = _motion_metrics(model, skeleton, settled, used, fps)
    before["foot_height_cm"] = _motion_metrics(model, skeleton, q, used, fps)["foot_height_cm"]
    metrics = {f"{k}_before": v for k, v in before.items()}
    metrics["floor_settle_cm"] = float(np.median(drop) * 100)

    if other_qpos is not None:
        other_poses = geom_poses(other_model, other_q)
        overlap = interpenetration(geom_poses(model, q), geom_poses(other_model, other_q))[0]
        metrics["interpenetration_mm_before"] = float(max(overlap.max(), 0.0) * 1000)
        other_shift = np.zeros((frames, 3))
        out, other_shift = _separate(model, out, other_poses, other_q, other_shift, config)

    out = fix_feet(model, skeleton, out, used, config)
    if other_qpos is not None:
        out, other_shift = _separate(model, out, other_poses, other_q, other_shift, config)
        out = fix_feet(model, skeleton, out, used, config, follow=False)
        out, other_shift = _separate(model, out, other_poses, other_q, other_shift, config)
        overlap = interpenetration(geom_poses(model, out), other_poses, -other_shift)[0]
        metrics["interpenetration_mm_after"] = float(max(overlap.max(), 0.0) * 1000)

    out = lift_above_floor(model, out, config.separation_smooth_frames)
    after = _motion_metrics(model, skeleton, out, used, fps)
    metrics.update({f"{k}_after": v for k, v in after.items()})
    metrics["contact_share"] = float(used.mean())
    return Cleaned(
        qpos=out,
        qvel=velocities(model, out, fps),
        points=keypoint_positions(model, out),
        contacts=used,
        settle=drop,
        metrics=metrics,
    )


def cleanup_pair(
    models: tuple[mujoco.MjModel, mujoco.MjModel],
    qpos: tuple[np.ndarray, np.ndarray],
    contacts: tuple[np.ndarray, np.ndarray],
    *,
    fps: float,
    config: LiftConfig = LiftConfig(),  # noqa: B008 (frozen, so a safe default)
    spans: tuple[tuple[int, int], tuple[int, int]] | None = None,
) -> tuple[Cleaned, Cleaned]:
    """`cleanup` of two fighters of one world, leaving no overlap between them.

    The first is cleaned against the second's input motion and makes
    `config.separation_share` of the separation; the second is then cleaned against the
    first's final motion and makes the rest (share 1), so the two results are checked against
    each other exactly.

    Args:
        models: each fighter's model (see `cleanup`).
        qpos: each fighter's (T_i, 35) motion over its own frames.
        contacts: each fighter's (T_i, 2) bool foot contacts.
        fps: frames per second.
        config: the settings.
        spans: each fighter's frames [start, end) on one timeline (T_i = end - start); None:
            both cover the same frames. Each is cleaned over its own frames only (filtered over
            a frame where it is absent, its first frames took on a stand-in's position 1 km
            away: a fighter entering 48 frames after the other was placed 214 m off); the other
            stands 1 km away where absent, out of reach.

    Returns:
        The two `Cleaned`, in the order given.
    """
    if spans is None:
        spans = ((0, len(qpos[0])), (0, len(qpos[1])))
    first = cleanup(
        models[0],
        qpos[0],
        contacts[0],
        fps=fps,
        config=config,
        other_qpos=_over(qpos[1], spans[1], spans[0]),
        other_model=models[1],
    )
    second = cleanup(
        models[1],
        qpos[1],
        contacts[1],
        fps=fps,
        config=replace(config, separation_share=1.0),
        other_qpos=_over(first.qpos, spans[0], spans[1]),
        other_model=models[0],
    )
    return first, second


def _over(qpos: np.ndarray, span: tuple[int, int], frames: tuple[int, int]) -> np.ndarray:
    """A fighter's ``qpos`` over ``span`` of a timeline, given over ``frames`` of it: where it
    is absent, it stands 1 km away (nothing can touch it), in its nearest pose."""
    (a, b), frame = span, np.arange(*frames)
    out = qpos[np.clip(frame, a, b - 1) - a].copy()
    out[(frame < a) | (frame >= b), 0] += 1000.0
    return out
