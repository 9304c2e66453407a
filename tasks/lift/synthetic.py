"""Synthetic ground truth for the lift: motion capture on our humanoid, seen by a random camera.

DeepMimic's example clips (Peng et al., "DeepMimic", ACM TOG 37(4), 2018; the copies in the
pybullet==3.2.7 wheel, pulled by `ringside assets pull --dev`) are retargeted to the boxer
humanoid, their BlazePose-33 keypoints taken from the humanoid's sites, projected through a
random pinhole camera, and given the noise the pose stage would add: 2D keypoints with a few
pixels of error and a per-frame metric 3D estimate (BlazePose's "world landmarks") with a
few centimetres. The lift's output is then scored against the truth (`tasks.lift.metrics`).

The clips are read and retargeted by `tasks.deepmimic`.

Shape letters: T frames, J = 33 BlazePose landmarks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.compiled import keypoint_positions
from models.humanoid.kinematics import (
    NQ,
)
from models.pose.types import BLAZEPOSE_33
from tasks.deepmimic import (
    CLIPS,
    FPS,
    Retargeted,
    clip_path,
    load_deepmimic,
    retarget_report,
)
from tasks.lift.camera import fov_intrinsics, look_at, project
from tasks.lift.metrics import HIPS


def truth_points(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """The humanoid's BlazePose-33 keypoints: its sites, in the world.

    Every landmark has a site, so none is NaN; some share one (see
    `models.humanoid.kinematics.BLAZEPOSE_TO_SITE`): the inner and outer eye corners sit on
    the eye, and the pinky, index and thumb all on the glove's knuckle point.

    Args:
        model: a compiled model of one boxer (e.g. from `boxer_mjcf(bones)`).
        qpos: (T, nq) configurations.

    Returns:
        (T, 33, 3) points in metres, z up.
    """
    q = np.asarray(qpos, dtype=np.float64)
    if q.ndim != 2:
        raise ValueError(f"qpos must have shape (T, nq), got {q.shape}")
    return keypoint_positions(model, q, keypoints=BLAZEPOSE_33)


# --------------------------------------------------------------------------
# Cameras
# --------------------------------------------------------------------------


def _range(name: str, value: tuple[float, float], positive: bool = True) -> tuple[float, float]:
    lo, hi = (float(v) for v in value)
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi and (lo > 0 or not positive)):
        raise ValueError(f"{name} must be a (low, high) range of positive numbers, got {value!r}")
    return lo, hi


def random_camera(
    rng: np.random.Generator,
    target: np.ndarray,
    *,
    distance: tuple[float, float] = (4.0, 7.0),
    height: tuple[float, float] = (1.0, 2.2),
    fov_deg: tuple[float, float] = (45.0, 70.0),
    size: tuple[int, int] = (1920, 1080),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An upright camera at a random bearing around `target`, looking at it.

    Bearing uniform in [0, 2 pi); horizontal distance from the target, height above the
    floor and field of view (across the longer image side) uniform in their ranges.

    Args:
        rng: the random generator (seeded by the caller).
        target: (3,) world point the camera looks at (e.g. the body's centre), metres.
        distance, height, fov_deg: (low, high) ranges in metres, metres, degrees.
        size: image (width, height) in pixels.

    Returns:
        K (3, 3), R (3, 3), t (3,): OpenCV convention, x_cam = R x_world + t.
    """
    g = np.asarray(target, dtype=np.float64)
    if g.shape != (3,) or not np.isfinite(g).all():
        raise ValueError(f"target must be a finite (3,) point, got {target!r}")
    d = rng.uniform(*_range("distance", distance))
    h = rng.uniform(*_range("height", height))
    fov = rng.uniform(*_range("fov_deg", fov_deg))
    bearing = rng.uniform(0.0, 2 * math.pi)
    centre = np.array([g[0] + d * math.cos(bearing), g[1] + d * math.sin(bearing), h])
    rotation, translation = look_at(centre, g)
    return fov_intrinsics(*size, fov), rotation, translation


def _camera(K: np.ndarray, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, ...]:
    k = np.asarray(K, dtype=np.float64)
    r = np.asarray(R, dtype=np.float64)
    tt = np.asarray(t, dtype=np.float64)
    for name, value, shape in (("K", k, (3, 3)), ("R", r, (3, 3)), ("t", tt, (3,))):
        if value.shape != shape:
            raise ValueError(f"{name} must have shape {shape}, got {value.shape}")
    return k, r, tt


def blazepose_like_world(points_world: np.ndarray, R: np.ndarray) -> np.ndarray:
    """World points as BlazePose gives its world landmarks: metres, origin at the hip centre
    (mean of the left and right hip), axes of the camera (x right, y down, z away from it).

    Args:
        points_world: (T, 33, 3) BlazePose-order points, metres, world frame.
        R: (3, 3) the camera's world-to-camera rotation.

    Returns:
        (T, 33, 3) points.
    """
    p = np.asarray(points_world, dtype=np.float64)
    if p.ndim != 3 or p.shape[1:] != (len(BLAZEPOSE_33), 3):
        raise ValueError(f"points_world must have shape (T, 33, 3), got {p.shape}")
    r = np.asarray(R, dtype=np.float64)
    if r.shape != (3, 3):
        raise ValueError(f"R must have shape (3, 3), got {r.shape}")
    cam = p @ r.T
    return cam - cam[:, list(HIPS)].mean(axis=1, keepdims=True)


# --------------------------------------------------------------------------
# The pose stage's noise
# --------------------------------------------------------------------------

# Landmark pairs (left, right): when the camera sees one side of the body, the far one of
# each pair is the one likely hidden behind it.
_LEFT_RIGHT = np.array(
    [
        (BLAZEPOSE_33.index(n), BLAZEPOSE_33.index("right" + n[4:]))
        for n in BLAZEPOSE_33
        if n.startswith("left")
    ]
)


def _hip_recentred_mpjpe_factor() -> float:
    """E|error| of a landmark / sigma when every coordinate gets N(0, sigma^2) noise and the
    set is then moved so the noisy hip centre is at the origin, averaged over the 33.

    A non-hip landmark's error is its noise minus the mean of the two hips' (variance
    1.5 sigma^2 per axis), a hip's is half the difference of the two (0.5 sigma^2); the
    norm of a 3D isotropic Gaussian with per-axis std s has mean 2 s sqrt(2 / pi).
    """
    chi = 2 * math.sqrt(2 / math.pi)
    others = len(BLAZEPOSE_33) - 2
    return chi * (others * math.sqrt(1.5) + 2 * math.sqrt(0.5)) / len(BLAZEPOSE_33)


def _ar1_noise(
    rng: np.random.Generator, shape: tuple[int, ...], scale: float, corr: float
) -> np.ndarray:
    """Gaussian noise with std `scale`, AR(1)-correlated along axis 0 with coefficient `corr`."""
    white = rng.standard_normal(shape) * scale
    if corr == 0.0:
        return white
    out = np.empty(shape)
    out[0] = white[0]
    keep = math.sqrt(1 - corr**2)  # keeps the stationary std at `scale`
    for k in range(1, shape[0]):
        out[k] = corr * out[k - 1] + keep * white[k]
    return out


@dataclass(frozen=True, eq=False)
class SyntheticInputs:
    """What the pose stage would hand the lift for one fighter.

    Attributes:
        keypoints_2d: (T, 33, 2) keypoints in pixels.
        confidence: (T, 33) in [0, 1]: 1 when seen, lower on the far side of the body, 0
            outside the image.
        world_landmarks: (T, 33, 3) per-frame metric 3D estimate, BlazePose's world-landmark
            frame (see `blazepose_like_world`).
    """

    keypoints_2d: np.ndarray
    confidence: np.ndarray
    world_landmarks: np.ndarray


def noisy_inputs(
    points_world: np.ndarray,
    K: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    rng: np.random.Generator,
    *,
    px_noise: float = 5.0,
    mm_noise: float = 60.0,
    temporal_corr: float = 0.0,
    far_side_confidence: float = 0.5,
    far_side_depth: float = 0.1,
) -> SyntheticInputs:
    """The true keypoints as a pose estimator would report them: projected with pixel noise,
    and as BlazePose-like world landmarks with metric noise.

    - 2D: `project`, plus N(0, px_noise^2) on each pixel coordinate.
    - 3D: the truth in BlazePose's world-landmark frame plus isotropic Gaussian noise, then
      moved so its own hip centre is the origin again (BlazePose's landmarks always are).
      The noise's std is set so that the expected hip-aligned MPJPE of the result
      (`tasks.lift.metrics.mpjpe_mm`) is `mm_noise` (per-axis std = mm_noise / 1.90).
    - Confidence: 1; `far_side_confidence` for the landmark of a left/right pair that is more
      than `far_side_depth` metres farther from the camera than its partner (hidden behind
      the body, as BlazePose's visibility would say); 0 outside the image, whose size is
      taken as twice K's principal point.

    Args:
        points_world: (T, 33, 3) true BlazePose-order points, metres, world frame.
        K: (3, 3) intrinsics; R (3, 3), t (3,): world to camera.
        rng: the random generator.
        px_noise: std of the 2D noise per coordinate, pixels.
        mm_noise: expected MPJPE of the 3D estimate, millimetres.
        temporal_corr: AR(1) coefficient in [0, 1) of both noises from frame to frame; 0
            draws every frame independently (the std stays the same either way).
        far_side_confidence: confidence of occluded far-side landmarks.
        far_side_depth: depth difference in metres past which a landmark counts as hidden.

    Returns:
        SyntheticInputs.
    """
    p = np.asarray(points_world, dtype=np.float64)
    if p.ndim != 3 or p.shape[1:] != (len(BLAZEPOSE_33), 3) or not np.isfinite(p).all():
        raise ValueError(f"points_world must be finite with shape (T, 33, 3), got {p.shape}")
    k, r, tt = _camera(K, R, t)
    for name, value in (("px_noise", px_noise), ("mm_noise", mm_noise)):
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a finite std >= 0, got {value!r}")
    if not 0.0 <= temporal_corr < 1.0:
        raise ValueError(f"temporal_corr must be in [0, 1), got {temporal_corr!r}")
    if not 0.0 <= far_side_confidence <= 1.0:
        raise ValueError(f"far_side_confidence must be in [0, 1], got {far_side_confidence!r}")

    clean = project(p, k, r, tt)
    keypoints = clean + _ar1_noise(rng, clean.shape, px_noise, temporal_corr)

    sigma = mm_noise / 1000.0 / _hip_recentred_mpjpe_factor()
    world = blazepose_like_world(p, r) + _ar1_noise(rng, p.shape, sigma, temporal_corr)
    world = world - world[:, list(HIPS)].mean(axis=1, keepdims=True)

    depth = (p @ r.T + tt)[..., 2]  # (T, 33)
    confidence = np.ones(depth.shape)
    left, right = _LEFT_RIGHT[:, 0], _LEFT_RIGHT[:, 1]
    gap = depth[:, left] - depth[:, right]
    confidence[:, left] = np.where(gap > far_side_depth, far_side_confidence, 1.0)
    confidence[:, right] = np.where(-gap > far_side_depth, far_side_confidence, 1.0)
    width, height = 2 * k[0, 2], 2 * k[1, 2]
    inside = (
        (depth > 0)
        & (clean[..., 0] >= 0)
        & (clean[..., 0] < width)
        & (clean[..., 1] >= 0)
        & (clean[..., 1] < height)
    )
    confidence = np.where(inside, confidence, 0.0)
    return SyntheticInputs(keypoints, confidence, world)


# --------------------------------------------------------------------------
# One case
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SyntheticCase:
    """A clip with known truth and the noisy inputs the lift gets for it.

    Attributes:
        clip_name: one of CLIPS.
        seed: the seed of its camera and noise.
        fps: frames per second (30).
        bones: the humanoid's bones (build its model with `boxer_mjcf(bones)`).
        qpos: (T, 35) true humanoid motion, z up, floor at z = 0.
        points: (T, 33, 3) true BlazePose-order keypoints in the world (`truth_points`).
        K, R, t: the camera: (3, 3) intrinsics, (3, 3) and (3,) world to camera.
        size: image (width, height) in pixels.
        inputs: the noisy 2D keypoints, confidences and world landmarks.
        retarget: how the clip was retargeted (scale, clipped joint limits).
    """

    clip_name: str
    seed: int
    fps: float
    bones: BoneLengths
    qpos: np.ndarray
    points: np.ndarray
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    size: tuple[int, int]
    inputs: SyntheticInputs
    retarget: Retargeted

    @property
    def world_landmarks_truth(self) -> np.ndarray:
        """(T, 33, 3) the noise-free world landmarks (`blazepose_like_world` of `points`)."""
        return blazepose_like_world(self.points, self.R)


def make_case(
    clip_name: str,
    seed: int,
    assets: str | Path,
    *,
    bones: BoneLengths = BoneLengths(),  # noqa: B008 (frozen, so a safe default)
    px_noise: float = 5.0,
    mm_noise: float = 60.0,
    temporal_corr: float = 0.0,
    size: tuple[int, int] = (1920, 1080),
    margin_px: float = 20.0,
    max_tries: int = 50,
) -> SyntheticCase:
    """Load, retarget, film and corrupt one clip, all from `seed`.

    The camera looks at the middle of the body's bounding box over the clip; cameras that
    would lose a true keypoint out of the image (within `margin_px` of its border) are drawn
    again, up to `max_tries` times (the last draw is kept; its outside points get
    confidence 0).

    Args:
        clip_name: one of CLIPS ("punch", "kick", "walk", "run").
        seed: seeds, with the clip's index in CLIPS, the one random generator used for
            the camera and the noise.
        assets: the assets folder (`storage.paths.data_paths().assets`), pulled with dev.
        bones, px_noise, mm_noise, temporal_corr: see `retarget` and `noisy_inputs`.
        size: image (width, height) in pixels.

    Returns:
        SyntheticCase at 30 frames per second.
    """
    clip = load_deepmimic(clip_path(assets, clip_name))
    retargeted = retarget_report(clip, bones, fps=FPS)
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(bones))
    assert model.nq == NQ
    points = truth_points(model, retargeted.qpos)
    # The clip's index joins the seed so one seed films each clip from its own camera.
    rng = np.random.default_rng([int(seed), CLIPS.index(clip_name)])
    target = (points.reshape(-1, 3).min(axis=0) + points.reshape(-1, 3).max(axis=0)) / 2
    for _ in range(max(1, max_tries)):
        K, R, t = random_camera(rng, target, size=size)
        uv = project(points, K, R, t)
        inside = (uv >= margin_px).all() and (uv <= np.array(size) - margin_px).all()
        if inside:
            break
    inputs = noisy_inputs(
        points, K, R, t, rng, px_noise=px_noise, mm_noise=mm_noise, temporal_corr=temporal_corr
    )
    return SyntheticCase(
        clip_name=clip_name,
        seed=int(seed),
        fps=FPS,
        bones=bones,
        qpos=retargeted.qpos,
        points=points,
        K=K,
        R=R,
        t=t,
        size=(int(size[0]), int(size[1])),
        inputs=inputs,
        retarget=retargeted,
    )


def evaluate_lift(
    case: SyntheticCase, config, workdir: Path, *, dist: np.ndarray | None = None
) -> dict[str, float]:
    """Run the lift stage (:func:`tasks.lift.stage.lift_video`) on one synthetic case and score
    its input and output against the truth.

    The stage gets the case's true intrinsics through a calibration file, as an analyst with a
    calibrated camera would; it finds the floor and the camera's pose itself. Its output, in its
    own world, is carried back to the truth's world through the two cameras before scoring.
    ``dist`` is the lens distortion the calibration file says the keypoints were seen through
    (none by default). Returns MPJPE / PA-MPJPE (mm) of the noisy 3D input and of the output,
    the output's median hip-centre placement error (mm), and the stage's own metrics.
    """
    from tasks.lift.camera import write_calibration
    from tasks.lift.metrics import mpjpe_mm, pa_mpjpe_mm
    from tasks.lift.stage import FighterTrack, lift_video

    calibration = workdir / "calibration.json"
    write_calibration(calibration, case.K, np.zeros(5) if dist is None else dist, case.size, 0.0)
    frames = len(case.points)
    track = FighterTrack(
        case.inputs.keypoints_2d, case.inputs.confidence, case.inputs.world_landmarks
    )
    output = lift_video(
        {"adversary": track},
        fps=case.fps,
        size=case.size,
        shots=[(0, 0, frames)],
        config=config,
        calibration=calibration,
    )
    ((_, _, camera),) = output.cameras
    R_est, t_est = camera.R, camera.t
    motion = output.motion["adversary"]
    lifted = np.full((frames, 33, 3), np.nan)
    # The case is at 30 fps, the rate the stage stores motion at: step k is frame k.
    lifted[motion.step] = motion.joints
    # Stage world -> camera -> truth world.
    in_truth_world = ((lifted @ R_est.T + t_est) - case.t) @ case.R
    # The noisy input: hip-centred landmarks in camera axes, turned into the world's axes.
    hips = case.points[:, list(HIPS)].mean(axis=1)
    noisy = case.inputs.world_landmarks @ case.R + hips[:, None]
    placed = np.linalg.norm(
        in_truth_world[:, list(HIPS)].mean(1) - case.points[:, list(HIPS)].mean(1), axis=-1
    )
    return {
        "placement_error_mm": float(np.nanmedian(placed) * 1000),
        "input_mpjpe_mm": mpjpe_mm(noisy, case.points),
        "input_pa_mpjpe_mm": pa_mpjpe_mm(noisy, case.points),
        "output_mpjpe_mm": mpjpe_mm(in_truth_world, case.points),
        "output_pa_mpjpe_mm": pa_mpjpe_mm(in_truth_world, case.points),
        **output.metrics,
    }
