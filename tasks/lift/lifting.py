"""Step 1 of the lift: one fighter's 2D keypoints and BlazePose world landmarks to 3D joints.

`lift_fighter` gives 3D joints per frame in the world frame. The start is BlazePose's world
landmarks, turned from camera axes into world axes and placed at the hip centre; a batched
L-BFGS over every frame's joint positions then minimises (`lift_energy`) confidence-weighted
reprojection error + bone-length constancy (one length per bone over the clip) + temporal
smoothness (second differences) + closeness to the landmarks' shape, and, once foot contacts
are detected (`detect_contacts`, from foot height and speed), feet on the floor without
sliding. Temporal fusion of monocular estimates with reprojection and bone/smoothness priors
follows e.g. Arnab et al., "Exploiting temporal context for 3D human pose estimation in the
wild", CVPR 2019, §3, and Peng et al., "SFV: Reinforcement learning of physical skills from
videos", SIGGRAPH Asia 2018, §4.2 (without SMPL: the unknowns are joint positions). `Lifter`
is the interface a learned temporal lifter (ONNX) can fill.

The next steps: `models.humanoid.fitting.fit_humanoid` (inverse kinematics of the humanoid to
these joints) and `tasks.lift.cleanup` (what a body cannot do, removed in MuJoCo).

Shape letters: T frames, J = 33 BlazePose landmarks (`BLAZEPOSE_33` order), B bones. Units:
metres, seconds; image coordinates in pixels. World frame: z up, floor z = 0. Cameras: OpenCV
pinhole, ``x_cam = R @ x_world + t`` (x right, y down, z forward).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import torch

from models.humanoid.boxer import BoneLengths
from models.humanoid.motion import (
    check_array,
    check_fps,
    clean_runs,
    gaussian_smooth,
    horizontal_speed,
)
from models.pose.types import BLAZEPOSE_33
from tasks.lift.camera import root_translations
from tasks.lift.config import LiftConfig
from tasks.lift.metrics import (
    BLAZEPOSE_BONES,
    HIPS,
    SOLES,
)

NUM_KEYPOINTS = len(BLAZEPOSE_33)


def _k(name: str) -> int:
    return BLAZEPOSE_33.index(name)


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
    p = check_array("points", points, (None, NUM_KEYPOINTS, 3))
    fps = check_fps(fps)
    soles = p[:, np.array(SOLES)]  # (T, 2, 2, 3)
    height = soles[..., 2].min(-1)
    middle = soles[..., :2].mean(2)  # (T, 2, 2)
    speed = horizontal_speed(middle, fps)
    raw = (height < config.contact_height_m) & (speed < config.contact_speed_m_s)
    return clean_runs(raw, config.contact_min_frames)


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
    kp = check_array("keypoints_2d", keypoints_2d, (None, NUM_KEYPOINTS, 2))
    frames = len(kp)
    if frames == 0:
        raise ValueError("keypoints_2d must hold at least one frame, got 0")
    conf = check_array("confidence", confidence, (frames, NUM_KEYPOINTS))
    landmarks = check_array("world_landmarks", world_landmarks, (frames, NUM_KEYPOINTS, 3))
    K = check_array("K", K, (3, 3))
    R = check_array("R", R, (3, 3))
    t = check_array("t", t, (3,))
    fps = check_fps(fps)
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
        root_init = check_array("root_init", root_init, (frames, 3))
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
