"""Cameras and the world frame: intrinsics, calibration files, the floor, triangulation.

Conventions: OpenCV pinhole cameras, ``x_cam = R @ x_world + t`` with camera axes x right, y down,
z forward; the world is z up with the floor at z = 0, in metres.

Monocular footage has no calibration, so the world is found from the fighters themselves: each
frame's metric 3D skeleton (BlazePose's world landmarks) is placed along the camera rays by the
translation that best reprojects it onto the 2D keypoints, which puts the feet in camera
coordinates; a plane through the lowest foot points over time is the floor, and the floor gives
the camera's height and pitch. Both fighters then share that world, at their metric distance.
BlazePose's skeletons have an average body's size; a fighter's known stature rescales his, and
the camera's height then comes from his ankles and ears (`camera_height`), every fighter
standing on that floor (`ground_fighters`).
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import least_squares

from models.pose.types import BLAZEPOSE_33
from tasks.errors import BadInput

FOOT_POINTS = np.array(
    [
        BLAZEPOSE_33.index(n)
        for n in (
            "left_ankle",
            "right_ankle",
            "left_heel",
            "right_heel",
            "left_foot_index",
            "right_foot_index",
        )
    ]
)
ANKLES = np.array([BLAZEPOSE_33.index("left_ankle"), BLAZEPOSE_33.index("right_ankle")])
SHOULDERS = np.array([BLAZEPOSE_33.index("left_shoulder"), BLAZEPOSE_33.index("right_shoulder")])
KNEES = np.array([BLAZEPOSE_33.index("left_knee"), BLAZEPOSE_33.index("right_knee")])
HIP_JOINTS = np.array([BLAZEPOSE_33.index("left_hip"), BLAZEPOSE_33.index("right_hip")])
EARS = np.array([BLAZEPOSE_33.index("left_ear"), BLAZEPOSE_33.index("right_ear")])
# The part of a standing body's height between its ankles and its ears: ankle 0.039 H, eye (the
# ears' level) 0.936 H in Drillis and Contini's proportions (Winter, Biomechanics and Motor
# Control of Human Movement, fig. 4.1).
STATURE_SHARE = 0.936 - 0.039


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated or guessed camera. K (3, 3); dist (5,) OpenCV k1 k2 p1 p2 k3; R (3, 3) and
    t (3,) world to camera; size (width, height) in pixels."""

    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    size: tuple[int, int]

    @property
    def centre(self) -> np.ndarray:
        """(3,) the camera's position in the world."""
        return -self.R.T @ self.t


def fov_intrinsics(width: int, height: int, fov_deg: float) -> np.ndarray:
    """(3, 3) K for a camera whose field of view across its longer side is ``fov_deg``."""
    if not 1.0 < fov_deg < 179.0:
        raise ValueError(f"fov_deg must be in (1, 179), got {fov_deg}")
    f = 0.5 * max(width, height) / math.tan(math.radians(fov_deg) / 2)
    return np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


def look_at(centre: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) of an upright OpenCV camera at `centre` looking at `target`.

    Camera axes: z along the view, x to the right parallel to the floor, y down.

    Args:
        centre: (3,) camera position, metres, z up.
        target: (3,) the point it looks at; not straight above or below `centre`.

    Returns:
        R (3, 3) and t (3,) with x_cam = R x_world + t.
    """
    c = np.asarray(centre, dtype=np.float64)
    g = np.asarray(target, dtype=np.float64)
    if c.shape != (3,) or g.shape != (3,):
        raise ValueError(f"centre and target must be (3,) points, got {c.shape} and {g.shape}")
    forward = g - c
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, (0.0, 0.0, 1.0))
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("target must not be straight above or below the camera centre")
    right = right / np.linalg.norm(right)
    down = np.cross(forward, right)
    rotation = np.stack([right, down, forward])
    return rotation, -rotation @ c


def project(points: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(..., 3) world points -> (..., 2) pixels (no distortion)."""
    cam = np.asarray(points) @ R.T + t
    uv = cam[..., :2] / cam[..., 2:3]
    return uv * np.diag(K)[:2] + K[:2, 2]


def read_qca(path: Path) -> list[tuple[str, Camera]]:
    """The cameras of a Qualisys ``.qca`` calibration file (Pose2Sim's samples use one).

    Intrinsics are stored in sensor units, 64 per pixel. Each camera's transform holds its
    position (millimetres) and a rotation whose y and z axes point opposite to OpenCV's; the
    convention was settled on the four-camera sample, where it is the only one of the 48
    axis permutations and sign flips under which both people triangulate consistently
    (median reprojection error 23 px, the next best 79 px; benchmarks/lift_multiview.py).
    Lens distortion is kept (k1, k2, p1, p2, k3).
    """
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as error:
        raise BadInput(str(path), f"is not a readable .qca calibration file ({error})") from None
    flip = np.diag([1.0, -1.0, -1.0])
    cameras = []
    for node in root.iter("camera"):
        serial = node.get("serial", f"cam{len(cameras) + 1:02d}")
        transform, intrinsic, fov = (
            node.find("transform"),
            node.find("intrinsic"),
            node.find("fov_video"),
        )
        if transform is None or intrinsic is None or fov is None:
            raise BadInput(str(path), f"camera {serial} lacks its transform, intrinsic or fov")
        try:
            a = {k: float(v) for k, v in transform.attrib.items()}
            i = {k: float(v) for k, v in intrinsic.attrib.items()}
            orientation = np.array([[a[f"r{r}{c}"] for c in (1, 2, 3)] for r in (1, 2, 3)])
            position = np.array([a["x"], a["y"], a["z"]]) / 1000.0
            K = (
                np.array(
                    [
                        [i["focalLengthU"], 0.0, i["centerPointU"]],
                        [0.0, i["focalLengthV"], i["centerPointV"]],
                        [0.0, 0.0, 64.0],
                    ]
                )
                / 64.0
            )
            dist = np.array(
                [
                    i["radialDistortion1"],
                    i["radialDistortion2"],
                    i["tangentalDistortion1"],
                    i["tangentalDistortion2"],
                    i["radialDistortion3"],
                ]
            )
            size = (
                int(fov.get("right")) - int(fov.get("left")) + 1,
                int(fov.get("bottom")) - int(fov.get("top")) + 1,
            )
        except (KeyError, TypeError, ValueError) as error:
            raise BadInput(str(path), f"camera {serial}: missing or bad value ({error})") from None
        R = flip @ orientation
        cameras.append((serial, Camera(K, dist, R, -R @ position, size)))
    if not cameras:
        raise BadInput(str(path), "holds no cameras")
    return cameras


def calibrate_chessboard(
    images: list[np.ndarray], *, board: tuple[int, int], square_m: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """Intrinsics from views of a chessboard (OpenCV's method; thesis appendix 2.7.1).

    ``board`` is the count of inner corners (columns, rows). Returns K (3, 3), dist (5,) and the
    RMS reprojection error in pixels. Raises ValueError when fewer than 3 views show the board.
    """
    pattern = np.zeros((board[0] * board[1], 3), np.float32)
    pattern[:, :2] = np.mgrid[: board[0], : board[1]].T.reshape(-1, 2) * square_m
    object_points, image_points, size = [], [], None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
    for image in images:
        grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        size = grey.shape[::-1]
        found, corners = cv2.findChessboardCorners(grey, board)
        if found:
            corners = cv2.cornerSubPix(grey, corners, (11, 11), (-1, -1), criteria)
            object_points.append(pattern)
            image_points.append(corners)
    if len(object_points) < 3:
        raise ValueError(
            f"the chessboard ({board[0]}x{board[1]} inner corners) was found in "
            f"{len(object_points)} of {len(images)} images; at least 3 are needed"
        )
    rms, K, dist, _, _ = cv2.calibrateCamera(object_points, image_points, size, None, None)
    return K, dist.ravel()[:5], float(rms)


def undistort(points: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """(..., 2) pixels seen through a lens with OpenCV distortion ``dist`` -> the pixels an
    ideal pinhole camera with intrinsics ``K`` would see; NaN stays NaN."""
    flat = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    out = np.full_like(flat, np.nan)
    seen = np.isfinite(flat).all(axis=1)
    if seen.any():
        out[seen] = cv2.undistortPoints(flat[seen].reshape(-1, 1, 2), K, dist, P=K).reshape(-1, 2)
    return out.reshape(np.shape(points))


def triangulate(points_2d: np.ndarray, weights: np.ndarray, cameras: list[Camera]) -> np.ndarray:
    """Multi-view linear triangulation (DLT), weighted by confidence.

    points_2d (V, ..., 2) pixels seen by V cameras (distortion removed here), weights (V, ...)
    in [0, 1]. Returns (..., 3) world points, NaN where fewer than two views have weight.
    """
    views = len(cameras)
    shape = points_2d.shape[1:-1]
    flat = points_2d.reshape(views, -1, 2)
    w = np.nan_to_num(weights.reshape(views, -1))
    undistorted = np.stack([undistort(flat[v], cam.K, cam.dist) for v, cam in enumerate(cameras)])
    projections = np.stack([cam.K @ np.hstack([cam.R, cam.t[:, None]]) for cam in cameras])
    out = np.full((flat.shape[1], 3), np.nan)
    for n in range(flat.shape[1]):
        good = (w[:, n] > 0) & np.isfinite(undistorted[:, n]).all(axis=1)
        if good.sum() < 2:
            continue
        rows = []
        for v in np.flatnonzero(good):
            u, vv = undistorted[v, n]
            P = projections[v]
            rows += [w[v, n] * (u * P[2] - P[0]), w[v, n] * (vv * P[2] - P[1])]
        _, _, vt = np.linalg.svd(np.array(rows))
        out[n] = vt[-1, :3] / vt[-1, 3]
    return out.reshape(*shape, 3)


def root_translations(
    keypoints_2d: np.ndarray, confidence: np.ndarray, world_landmarks: np.ndarray, K: np.ndarray
) -> np.ndarray:
    """Per frame, the camera-frame position of a metric skeleton's hip centre.

    Solves, in least squares, for the translation T with ``project(L + T) ≈ p`` for every joint:
    ``(u - cx)(Z + Tz) = fx (X + Tx)`` and likewise for v are linear in T.

    keypoints_2d (F, J, 2) pixels, confidence (F, J), world_landmarks (F, J, 3) metres in camera
    axes about the hip centre. Returns (F, 3); NaN where fewer than 3 joints are usable.
    """
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    out = np.full((len(keypoints_2d), 3), np.nan)
    for f in range(len(keypoints_2d)):
        good = (
            (confidence[f] > 0.3)
            & np.isfinite(keypoints_2d[f]).all(1)
            & np.isfinite(world_landmarks[f]).all(1)
        )
        if good.sum() < 3:
            continue
        (u, v), (X, Y, Z) = keypoints_2d[f, good].T, world_landmarks[f, good].T
        w = np.sqrt(confidence[f, good])
        a = np.zeros((2 * len(u), 3))
        b = np.zeros(2 * len(u))
        a[0::2, 0], a[0::2, 2], b[0::2] = fx, -(u - cx), (u - cx) * Z - fx * X
        a[1::2, 1], a[1::2, 2], b[1::2] = fy, -(v - cy), (v - cy) * Z - fy * Y
        ww = np.repeat(w, 2)
        out[f] = np.linalg.lstsq(a * ww[:, None], b * ww, rcond=None)[0]
    return out


def body_up(world_landmarks: np.ndarray) -> np.ndarray:
    """(3,) unit up direction in camera axes: the mean direction from the ankles' midpoint to
    the shoulders' midpoint over all frames (a boxer leans, but not on average).
    world_landmarks (F, 33, 3)."""
    ankles = world_landmarks[:, ANKLES].mean(1)
    shoulders = world_landmarks[:, SHOULDERS].mean(1)
    axis = shoulders - ankles
    axis = axis[np.isfinite(axis).all(1)]
    if not len(axis):
        raise ValueError("no frame shows both ankles and shoulders: the floor cannot be found")
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    mean = axis.mean(0)
    return mean / np.linalg.norm(mean)


def fit_floor(
    feet: np.ndarray, up: np.ndarray, *, percentile: float = 5.0
) -> tuple[np.ndarray, float]:
    """The floor ``n @ x + d = 0`` (camera coordinates) with normal ``up``, at a low percentile
    of the feet's heights along it (the feet that touch the floor; a robust minimum).

    Two fighters' feet lie near a line, which leaves a plane fitted to them free to turn about
    it, hence the normal from the bodies. feet (N, 3); up (3,) unit, pointing up.
    """
    heights = feet[np.isfinite(feet).all(1)] @ up
    if len(heights) < 3:
        raise ValueError(f"need at least 3 foot points to find the floor, got {len(heights)}")
    return up, -float(np.percentile(heights, percentile))


def world_from_floor(normal: np.ndarray, d: float) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera R, t for a floor ``n @ x + d = 0`` in camera coordinates: world z along n,
    origin under the camera on the floor, world x along the camera's x laid flat."""
    z = normal / np.linalg.norm(normal)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    cam_from_world = np.stack([x, y, z], axis=1)  # world axes as columns, in camera coordinates
    origin = -d * z  # the camera's foot on the floor, in camera coordinates
    return cam_from_world, origin


def stature(points: np.ndarray) -> float:
    """A body's standing height (m) from its joints, whatever its pose.

    The chain from the ankles to the ears straightened: shin, thigh (both sides), mid-hip to
    mid-shoulder and mid-shoulder to mid-ear, each the median of its lengths over the frames,
    summed and divided by `STATURE_SHARE`, the part of standing height between ankle and ear.
    Bending, crouching and walking leave it unchanged; only the foot below the ankle and the
    skull above the ear are taken from average proportions.

    points (F, 33, 3) metres, any frame and origin; NaN where unseen. Raises ValueError when a
    segment is never seen.
    """

    def middle(pair: np.ndarray) -> np.ndarray:
        return points[:, pair].mean(1)

    total = 0.0
    for name, a, b in (
        ("shin", points[:, ANKLES], points[:, KNEES]),
        ("thigh", points[:, KNEES], points[:, HIP_JOINTS]),
        ("trunk", middle(HIP_JOINTS), middle(SHOULDERS)),
        ("neck", middle(SHOULDERS), middle(EARS)),
    ):
        lengths = np.linalg.norm(a - b, axis=-1).ravel()
        lengths = lengths[np.isfinite(lengths)]
        if not len(lengths):
            raise ValueError(f"the body's {name} is never seen: its stature cannot be measured")
        total += float(np.median(lengths))
    return total / STATURE_SHARE


def _lowest_feet(world: np.ndarray, roots: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(F, 3) per frame, a placed fighter's lowest foot point along `up` (camera coordinates),
    the likeliest on the floor. world (F, 33, 3) about the hip centre, roots (F, 3)."""
    points = world[:, FOOT_POINTS] + roots[:, None]
    heights = np.where(np.isfinite(points).all(2), points @ up, np.inf)
    return points[np.arange(len(points)), np.argmin(heights, axis=1)]


def camera_height(
    fighters: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    K: np.ndarray,
    up: np.ndarray,
    guess: float,
) -> float | None:
    """The camera's height (m) over the floor from fighters of known size, by single-view
    metrology (Criminisi, Reid and Zisserman, 2000): a body standing on the floor with its
    ankles on their camera ray has its ears on theirs only at one camera height.

    Per frame, the fighter's lowest foot point is on the floor, its ankles' midpoint is on the
    ray through their 2D midpoint at the height above its lowest foot that its skeleton gives,
    and its ears' midpoint is that far above it along `up` that the skeleton's ankle-to-ear
    height says: a posture, so the skeleton must be at the fighter's true size. The height is
    the one whose ears reproject best (least squares in pixels, over all frames that see both
    ankles and both ears with confidence over 0.5).

    Only the upright part of the ankle-to-ear line is taken from the skeleton: on the sample
    filmed by four calibrated cameras (benchmarks/lift_multiview.py) the whole 3D offset, lean
    included, put the camera 3 cm lower with BlazePose's full model and 5 cm lower with its
    heavy one, and placing the whole skeleton by all its joints (`root_translations`) put it 11
    cm too high: BlazePose's proportions are an average body's, its posture is closer to true.

    fighters: per fighter (keypoints_2d (F, 33, 2), confidence (F, 33), world_landmarks
    (F, 33, 3) at its true size); up (3,) unit, camera coordinates; guess: a height (m) to start
    from. None where no frame serves.
    """
    rays, ears, above = [], [], []
    inverse = np.linalg.inv(K)
    for keypoints, confidence, world in fighters:
        seen = (confidence[:, np.r_[ANKLES, EARS]] > 0.5).all(1)
        seen &= np.isfinite(keypoints[:, np.r_[ANKLES, EARS]]).all((1, 2))
        seen &= np.isfinite(world[:, np.r_[ANKLES, EARS]]).all((1, 2))
        ankle_px = keypoints[seen][:, ANKLES].mean(1)
        ray = np.c_[ankle_px, np.ones(len(ankle_px))] @ inverse.T
        ankle = world[seen][:, ANKLES].mean(1)
        feet = np.where(np.isfinite(world[seen][:, FOOT_POINTS]), world[seen][:, FOOT_POINTS], 0)
        ankle_height = np.max((ankle[:, None] - feet) @ up, axis=1)
        ear_height = (world[seen][:, EARS].mean(1) - ankle) @ up
        downward = ray @ up < 0  # an ankle above the horizon cannot stand on a floor below
        rays.append(ray[downward])
        ears.append(keypoints[seen][downward][:, EARS].mean(1))
        above.append(np.c_[ankle_height, ear_height][downward])
    ray, ear, (ankle_height, ear_height) = (
        np.concatenate(rays),
        np.concatenate(ears),
        np.concatenate(above).T,
    )
    if not len(ray):
        return None

    def misfit(height: np.ndarray) -> np.ndarray:
        ankle = ((ankle_height - height[0]) / (ray @ up))[:, None] * ray
        projected = (ankle + ear_height[:, None] * up) @ K.T
        return (projected[:, :2] / projected[:, 2:] - ear).ravel()

    # Below its ankles' height the camera would see them from under the floor.
    lowest = float(ankle_height.max()) + 1e-3
    return float(least_squares(misfit, [max(guess, 2 * lowest)], bounds=(lowest, np.inf)).x[0])


def ground_fighters(
    fighters: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    K: np.ndarray,
    size: tuple[int, int],
    statures: list[float | None] | None = None,
) -> tuple[Camera, list[np.ndarray], list[float]]:
    """One world for all fighters of a shot, from their own bodies.

    Each frame's metric skeleton is placed by `root_translations`, which puts the feet in
    camera coordinates. BlazePose's skeletons have an average body's size, and every distance
    follows from it. With no stature known, the floor lies under the feet of all the fighters
    (`fit_floor`), and the camera's height and pitch come from it.

    A known stature (m) scales its fighter's skeleton to it (`stature`), and the camera's height
    comes from those fighters (`camera_height`). Every fighter is then moved along the camera
    rays until its feet stand on that floor: one of known stature keeps its size; one of
    unknown stature is scaled with its distance (`root_translations` is linear in the
    skeleton's size, so it comes out the size that stands it on the floor), or by the known
    fighters' mean factor where its own feet are too few to find its floor.

    fighters: per fighter (keypoints_2d (F, 33, 2), confidence (F, 33), world_landmarks
    (F, 33, 3)); statures: per fighter, metres or None. Returns the camera, per fighter its hip
    centre in the world per frame (F, 3), NaN where it could not be placed, and per fighter the
    factor its skeleton was scaled by.
    """
    statures = statures or [None] * len(fighters)
    if len(statures) != len(fighters):
        raise ValueError(f"got {len(statures)} statures for {len(fighters)} fighters")
    scales = [
        1.0 if height is None else height / stature(world)
        for (_, _, world), height in zip(fighters, statures, strict=True)
    ]
    fighters = [(k, c, w * s) for (k, c, w), s in zip(fighters, scales, strict=True)]
    roots = [root_translations(k, c, w, K) for k, c, w in fighters]
    up = body_up(np.concatenate([w for _, _, w in fighters]))
    feet = [_lowest_feet(w, r, up) for (_, _, w), r in zip(fighters, roots, strict=True)]
    known = [i for i, height in enumerate(statures) if height is not None]
    _, height = fit_floor(np.concatenate([feet[i] for i in known or range(len(feet))]), up)
    if known:
        height = camera_height([fighters[i] for i in known], K, up, height) or height
        mean_known = float(np.mean([scales[i] for i in known]))
        for i, placed in enumerate(feet):
            try:
                own = fit_floor(placed, up)[1]
            except ValueError:  # too few placed feet
                own = 0.0
            factor = height / own if own > 0 else mean_known if statures[i] is None else 1.0
            roots[i] = roots[i] * factor
            if statures[i] is None:
                scales[i] *= factor
    R, t = world_from_floor(up, height)
    camera = Camera(K, np.zeros(5), R, t, size)
    return camera, [(r - t) @ R for r in roots], scales


def stature_notes(known: dict[str, float | None], joints: dict[str, np.ndarray]) -> list[str]:
    """Where one fighter's stature is known and another's is not, a note per unknown one saying
    how tall its lifted body came out. known: role -> metres or None; joints: role -> its lifted
    joints (F, 33, 3)."""
    given = [role for role, height in known.items() if height is not None]
    if not given:
        return []
    notes = []
    for role, points in joints.items():
        if known.get(role) is None and np.isfinite(points).any():
            notes.append(
                f"the {role}'s height is unknown (lift.{role}_height_m): scaled to stand on the "
                f"floor that the {given[0]}'s known height sets, the {role} comes out "
                f"{stature(points):.2f} m tall"
            )
    return notes


def write_calibration(
    path: Path, K: np.ndarray, dist: np.ndarray, size: tuple[int, int], rms_px: float
) -> None:
    """Save intrinsics as JSON: K (3x3), dist (5), size [width, height], rms_px."""
    path.write_text(
        json.dumps(
            {"K": K.tolist(), "dist": list(map(float, dist)), "size": list(size), "rms_px": rms_px},
            indent=2,
        )
        + "\n"
    )


def read_calibration(path: Path) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """K (3, 3), dist (5,) and size (width, height) from a file :func:`write_calibration` wrote.

    Raises :class:`BadInput` naming the file and what is wrong with it.
    """
    try:
        data = json.loads(path.read_text())
        K = np.array(data["K"], dtype=np.float64)
        dist = np.array(data["dist"], dtype=np.float64)
        width, height = (int(v) for v in data["size"])
    except FileNotFoundError:
        raise BadInput(str(path), "calibration file not found") from None
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise BadInput(
            str(path),
            f"is not a calibration file ({type(error).__name__}: "
            f"{error}); expected JSON with K, dist and size",
        ) from None
    if K.shape != (3, 3) or dist.shape != (5,) or not np.isfinite(K).all() or K[0, 0] <= 0:
        raise BadInput(
            str(path),
            f"has K of shape {K.shape} and dist of shape {dist.shape}; "
            "expected a 3x3 K with positive focal length and 5 dist values",
        )
    return K, dist, (width, height)
