"""The monocular lift against a multi-view reference on real footage.

The bundled samples are filmed by four calibrated cameras each; this uses the
two-person one (both fighters). The pose stage's functions run on each camera's video with
BlazePose's heavy landmark model, and the 2D keypoints of all four views are triangulated with
the calibration (``Calib.qca.txt``) into a 3D reference; the lift stage then runs on camera 1
alone, on the pose stage's default (full) model, given only that camera's intrinsics, and its
output is compared with the reference in camera 1's coordinates: MPJPE (hip-centred) and
PA-MPJPE in mm over the 13 body joints (shoulders, elbows, wrists, hips, knees, ankles, nose),
and the error of each fighter's placement and of the distance
between them. Two yardsticks beside it: BlazePose's own 3D (its world landmarks, which the lift
starts from) against the same reference, and both errors on the reference points whose views
agree (each view used within ``AGREE_PX`` of the triangulated point): where the views disagree
by a hundred pixels or more, the reference is not a truth. What limits the lift is printed with
them: each view's keypoints against the triangulation of the other three (camera 1's are the
lift's only input) and each fighter's worst joints.

The people's true statures are measured on the reference (`tasks.lift.camera.stature` on the
points whose views agree), and camera 1 is lifted again given both, then each alone
(`lift.adversary_height_m`, `lift.opponent_height_m`): the camera's height, each lifted body's
stature, PA-MPJPE and placement error are printed beside the default lift's, whose scale is
BlazePose's average body. Each person's lowest foot point over the calibration's floor is
printed with the statures: the man stands on a platform.

Why the heavy model for the reference: a reference triangulated from the lift's own detector
inherits that detector's mistakes, and the full model puts the man's raised elbows and wrists
100-200 px off in views 2 and 4. The heavy model's four views agree better (its reprojection
error and agreement are printed beside the full model's); the error against the full model's
reference is printed too, as are the errors of a lift from the heavy model (`pose.pose_model`).
Last line: ``multiview_pa_mpjpe_mm: N mm`` (the default lift, every point).
"""

from __future__ import annotations

import itertools
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen rendering, as `ringside` sets it
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._common import FPS, FRAMES, lift_sample, sample_fighters  # noqa: E402
from models.pose.types import BLAZEPOSE_33  # noqa: E402
from storage.assets import HEAVY_LANDMARKER, pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.lift.camera import (  # noqa: E402
    FOOT_POINTS,
    read_qca,
    stature,
    triangulate,
    write_calibration,
)
from tasks.lift.config import LiftStageConfig  # noqa: E402
from tasks.lift.metrics import HIPS, mpjpe_mm, pa_mpjpe_mm, procrustes_align  # noqa: E402

BODY = [0, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28]
NAMES = [BLAZEPOSE_33[j] for j in BODY]
ROLES = ("adversary", "opponent")
AGREE_PX = 30.0


def view_errors_px(X: np.ndarray, points: np.ndarray, cameras) -> np.ndarray:
    """(V, ...) pixel distance of each view's keypoint from the projection of ``X``."""
    errors = []
    for view, cam in enumerate(cameras):
        c = X @ cam.R.T + cam.t
        uv = c[..., :2] / c[..., 2:] * np.diag(cam.K)[:2] + cam.K[:2, 2]
        errors.append(np.linalg.norm(uv - points[view], axis=-1))
    return np.stack(errors)


def reprojection_px(points: np.ndarray, weights: np.ndarray, cameras) -> float:
    errors = view_errors_px(triangulate(points, weights, cameras), points, cameras)
    return float(np.nanmean(np.nanmedian(errors, axis=tuple(range(1, errors.ndim)))))


def labelled_reference(tracks: list, cams: list) -> tuple[dict, dict, float]:
    """Each fighter triangulated from every view (which fighter is which in each view: the
    labelling that triangulates best), where each point's views agree, and the median
    reprojection error per person."""

    def views(order: list, person: int) -> tuple[np.ndarray, np.ndarray]:
        """One person's keypoints in every view (V, F, 33, 2) and their weights (V, F, 33)."""
        seen = [t[o[person]] for t, o in zip(tracks, order, strict=True)]
        return (
            np.stack([s.keypoints for s in seen]),
            np.stack([(s.confidence > 0.5).astype(float) for s in seen]),
        )

    best = None
    for swaps in itertools.product((False, True), repeat=len(cams) - 1):
        order = [ROLES] + [ROLES[::-1] if s else ROLES for s in swaps]
        error = 0.0
        for person in range(2):
            pts, w = views(order, person)
            error += reprojection_px(pts[:, :, BODY], w[:, :, BODY], cams)
        if best is None or error < best[0]:
            best = (error, order)
    error, order = best
    reference, agree, left_out = {}, {}, {}
    for person, role in enumerate(ROLES):
        pts, w = views(order, person)
        reference[role] = triangulate(pts, w, cams)
        errors = np.where(w > 0, view_errors_px(reference[role], pts, cams), 0.0)
        agree[role] = errors.max(axis=0) < AGREE_PX
        left_out[role] = []
        for view in range(len(cams)):
            others = [v for v in range(len(cams)) if v != view]
            X = triangulate(
                pts[others][:, :, BODY], w[others][:, :, BODY], [cams[v] for v in others]
            )
            off = view_errors_px(X, pts[:, :, BODY], cams)[view][w[view][:, BODY] > 0]
            left_out[role].append(float(np.nanmedian(off)))
    return reference, agree, error / 2, left_out


def lift(
    tracks: dict, cam1, tmp: Path, config: LiftStageConfig | None = None
) -> tuple[dict, np.ndarray, np.ndarray, float]:
    """Camera 1's fighters lifted by the lift stage with its default settings (or ``config``):
    the motion rows and the estimated camera (rotation, translation, height)."""
    calibration = tmp / "cam01.json"
    write_calibration(calibration, cam1.K, cam1.dist, cam1.size, 0.0)
    out = lift_sample(tracks, calibration, config)
    camera = out.rows["lift_cameras"][0]
    return (
        out.rows["lift_motion"],
        np.reshape(camera.R, (3, 3)),
        np.asarray(camera.t),
        camera.height_m,
    )


def lifted_joints(motion: dict, role: str) -> np.ndarray:
    """(T, 33, 3) a fighter's lifted joints, world frame."""
    return motion["joints"][motion["role"] == role].reshape(-1, 33, 3)


def in_camera(motion: dict, role: str, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, ...]:
    """A fighter's lifted body joints in camera 1's frame, and the 60 fps frames they are at."""
    mine = motion["role"] == role
    ours = np.full((FRAMES, 33, 3), np.nan)
    frames = np.round(motion["time_s"][mine] * FPS).astype(int)  # 30 Hz steps -> 60 fps
    ours[frames] = motion["joints"][mine].reshape(-1, 33, 3)
    return (ours @ R.T + t)[frames][:, BODY], frames


def true_statures(reference: dict, agree: dict) -> dict[str, float]:
    """Each person's standing height (m) from the triangulated joints whose views agree."""
    return {
        role: stature(np.where(agree[role][..., None], reference[role], np.nan)) for role in ROLES
    }


def lift_errors(motion: dict, R: np.ndarray, t: np.ndarray, reference: dict, cam1) -> dict:
    """Per fighter, (PA-MPJPE mm, median placement error of the hip centre mm) in camera 1."""
    body_hips = [BODY.index(h) for h in HIPS]
    out = {}
    for role in ROLES:
        ours, frames = in_camera(motion, role, R, t)
        ref = (reference[role] @ cam1.R.T + cam1.t)[frames][:, BODY]
        placed = np.linalg.norm(ours[:, body_hips].mean(1) - ref[:, body_hips].mean(1), axis=-1)
        out[role] = (pa_mpjpe_mm(ours, ref), float(np.nanmedian(placed)) * 1000)
    return out


def main() -> None:
    assets = data_paths().assets
    pull(assets, log=lambda _line: None)
    folder = assets / "samples" / "multi_person"
    cameras = read_qca(folder / "Calib.qca.txt")
    cams = [cam for _, cam in cameras]
    cam1 = cams[0]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        views = [folder / f"{name}.mp4" for name, _ in cameras]
        heavy = [sample_fighters(v, assets, assets / HEAVY_LANDMARKER) for v in views]
        full = [sample_fighters(v, assets) for v in views]
        reference, agree, error, left_out = labelled_reference(heavy, cams)
        full_reference, full_agree, full_error, _ = labelled_reference(full, cams)
        motion, R_est, t_est, height = lift(full[0], cam1, tmp)
        statures = true_statures(reference, agree)
        sized = {
            f"{', '.join(given)} known": lift(
                full[0],
                cam1,
                tmp,
                LiftStageConfig(**{f"{r}_height_m": statures[r] for r in given}),
            )
            for given in (ROLES, ROLES[:1], ROLES[1:])
        }
        heavy_motion, heavy_R, heavy_t, heavy_height = lift(heavy[0], cam1, tmp)

    def shares(agreeing: dict) -> str:
        return ", ".join(f"{agreeing[r][:, BODY].mean():.0%} ({r})" for r in ROLES)

    print(
        f"reference: BlazePose heavy in 4 views triangulated, median reprojection {error:.1f} px "
        f"per person, views within {AGREE_PX:g} px of it on {shares(agree)} of the points "
        f"(the full model: {full_error:.1f} px, {shares(full_agree)})"
    )
    for role in ROLES:
        shown = ", ".join(f"{px:.0f}" for px in left_out[role])
        print(
            f"{role}: each view's keypoints from the other three views' triangulation, median "
            f"px (views 1-4): {shown}"
        )
    print(f"camera 1 height: lift {height:.2f} m, calibration {cam1.centre[2]:.2f} m")
    print(
        "statures on the reference (views agreeing): "
        + ", ".join(f"{r} {statures[r]:.3f} m" for r in ROLES)
        + "; lowest foot point over the calibration's floor, median per frame: "
        + ", ".join(
            f"{r} {np.nanmedian(np.min(reference[r][:, FOOT_POINTS, 2], axis=1)) * 100:+.1f} cm"
            for r in ROLES
        )
    )
    for name, (m_, R_, t_, camera_height) in {
        "no stature known": (motion, R_est, t_est, height),
        **sized,
    }.items():
        errors = lift_errors(m_, R_, t_, reference, cam1)
        print(
            f"{name:26s} camera height {camera_height:.3f} m "
            f"({(camera_height - cam1.centre[2]) * 100:+.1f} cm); lifted stature, PA-MPJPE, "
            "placement error: "
            + "; ".join(
                f"{r} {stature(lifted_joints(m_, r)):.3f} m, {pa:.1f} mm, {placed:.0f} mm"
                for r, (pa, placed) in errors.items()
            )
        )
    results, hips = [], {}
    for role in ROLES:
        ours_cam, frames = in_camera(motion, role, R_est, t_est)
        ref_cam = (reference[role] @ cam1.R.T + cam1.t)[frames][:, BODY]
        body_hips = [BODY.index(h) for h in HIPS]
        hip_error = np.linalg.norm(
            ours_cam[:, body_hips].mean(1) - ref_cam[:, body_hips].mean(1), axis=-1
        )
        hips[role] = (ours_cam[:, body_hips].mean(1), ref_cam[:, body_hips].mean(1))
        m = mpjpe_mm(ours_cam, ref_cam, root=body_hips)
        pa = pa_mpjpe_mm(ours_cam, ref_cam)
        results.append(pa)
        print(
            f"{role:9s} MPJPE {m:6.1f} mm  PA-MPJPE {pa:6.1f} mm  "
            f"placement error {np.nanmedian(hip_error) * 1000:6.0f} mm (median, camera 1 frame)"
        )
        world = full[0][role].world.reshape(FRAMES, 33, 3)[frames][:, BODY]
        good = agree[role][frames][:, BODY]
        lift_error, world_error = (
            np.linalg.norm(procrustes_align(points, ref_cam) - ref_cam, axis=-1) * 1000
            for points in (ours_cam, world)
        )
        lift_good, world_good = np.nanmean(lift_error[good]), np.nanmean(world_error[good])
        worst = np.argsort(np.nanmean(lift_error, axis=0))[::-1][:3]
        print(
            f"{'':9s} worst joints (lift, mm): "
            + ", ".join(f"{NAMES[j]} {np.nanmean(lift_error[:, j]):.0f}" for j in worst)
        )
        print(
            f"{'':9s} BlazePose's own 3D PA-MPJPE {np.nanmean(world_error):6.1f} mm; where the "
            f"views agree within {AGREE_PX:g} px ({good.mean():.0%} of the points): lift "
            f"{lift_good:.1f} mm, BlazePose {world_good:.1f} mm"
        )
    ours_gap = np.linalg.norm(hips["adversary"][0] - hips["opponent"][0], axis=-1)
    ref_gap = np.linalg.norm(hips["adversary"][1] - hips["opponent"][1], axis=-1)
    print(
        f"distance between the fighters: lift {np.nanmean(ours_gap):.2f} m, "
        f"reference {np.nanmean(ref_gap):.2f} m"
    )
    others = []
    for name, (m_, R_, t_), ref in (
        ("lifted from the heavy model", (heavy_motion, heavy_R, heavy_t), reference),
        ("against the full model's reference", (motion, R_est, t_est), full_reference),
    ):
        errors = []
        for role in ROLES:
            ours_cam, frames = in_camera(m_, role, R_, t_)
            errors.append(pa_mpjpe_mm(ours_cam, (ref[role] @ cam1.R.T + cam1.t)[frames][:, BODY]))
        others.append(f"{name}: {errors[0]:.1f} / {errors[1]:.1f} mm")
    print(
        f"PA-MPJPE adversary / opponent {others[0]} (camera height {heavy_height:.2f} m); "
        f"{others[1]}"
    )
    print(f"multiview_pa_mpjpe_mm: {np.mean(results):.1f} mm")


if __name__ == "__main__":
    main()
