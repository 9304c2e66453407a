"""The monocular lift against a multi-view reference on real footage.

The bundled samples are filmed by four calibrated cameras each; this uses the
two-person one (both fighters). The pose stage's functions run
on each camera's video; the 2D keypoints of all four views are triangulated with the
calibration (``Calib.qca.txt``) into a 3D reference; the lift stage then runs on camera 1 alone,
given only that camera's intrinsics, and its output is compared with the reference in camera 1's
coordinates: MPJPE (hip-centred) and PA-MPJPE in mm over the 13 body joints (shoulders, elbows,
wrists, hips, knees, ankles, nose), and the error of each fighter's placement and of the distance
between them. Two yardsticks beside it: BlazePose's own 3D (its world landmarks, which the lift
starts from) against the same reference, and both errors on the reference points whose views
agree (each view used within ``AGREE_PX`` of the triangulated point): where the views disagree
by a hundred pixels or more, the reference is not a truth. Last line:
``multiview_pa_mpjpe_mm: N mm`` (every point).
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

from benchmarks._common import FPS, FRAMES, SIZE, sample_fighters  # noqa: E402
from storage.assets import pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.lift.camera import read_qca, triangulate, write_calibration  # noqa: E402
from tasks.lift.config import LiftStageConfig  # noqa: E402
from tasks.lift.metrics import HIPS, mpjpe_mm, pa_mpjpe_mm, procrustes_align  # noqa: E402
from tasks.lift.stage import lift_video  # noqa: E402

BODY = [0, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28]
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


def main() -> None:
    assets = data_paths().assets
    pull(assets, log=lambda _line: None)
    folder = assets / "samples" / "multi_person"
    cameras = read_qca(folder / "Calib.qca.txt")
    with tempfile.TemporaryDirectory() as tmp:
        tracks = [sample_fighters(folder / f"{name}.mp4", assets, Path(tmp)) for name, _ in cameras]
        cams = [cam for _, cam in cameras]
        # Which fighter is which in each view: the labelling that triangulates best.
        best = None
        for swaps in itertools.product((False, True), repeat=len(cams) - 1):
            order = [ROLES] + [ROLES[::-1] if s else ROLES for s in swaps]
            error = 0.0
            for person in range(2):
                pts = np.stack(
                    [t[o[person]].keypoints[:, BODY] for t, o in zip(tracks, order, strict=True)]
                )
                w = np.stack(
                    [
                        (t[o[person]].confidence[:, BODY] > 0.5).astype(float)
                        for t, o in zip(tracks, order, strict=True)
                    ]
                )
                error += reprojection_px(pts, w, cams)
            if best is None or error < best[0]:
                best = (error, order)
        error, order = best
        reference, agree = {}, {}
        for person, role in enumerate(ROLES):
            pts = np.stack([t[o[person]].keypoints for t, o in zip(tracks, order, strict=True)])
            w = np.stack(
                [
                    (t[o[person]].confidence > 0.5).astype(float)
                    for t, o in zip(tracks, order, strict=True)
                ]
            )
            reference[role] = triangulate(pts, w, cams)
            errors = np.where(w > 0, view_errors_px(reference[role], pts, cams), 0.0)
            agree[role] = errors.max(axis=0) < AGREE_PX
        cam1 = cams[0]
        calibration = Path(tmp) / "cam01.json"
        write_calibration(calibration, cam1.K, cam1.dist, cam1.size, 0.0)
        out = lift_video(
            tracks[0],
            key="mv",
            video_id="cam01",
            fps=FPS,
            size=SIZE,
            shots=[(0, 0, FRAMES)],
            config=LiftStageConfig(),
            calibration=calibration,
            artifacts=Path(tmp),
        )
    camera = out.rows["lift_cameras"][0]
    R_est, t_est = np.reshape(camera[5], (3, 3)), np.asarray(camera[6])
    motion = out.rows["lift_motion"]
    print(f"reference: 4 views triangulated, median reprojection {error / 2:.1f} px per person")
    print(f"camera 1 height: lift {camera[7]:.2f} m, calibration {cam1.centre[2]:.2f} m")
    results, hips = [], {}
    for role in ROLES:
        mine = motion["role"] == role
        ours = np.full((FRAMES, 33, 3), np.nan)
        frames = np.round(motion["time_s"][mine] * FPS).astype(int)  # 30 Hz steps -> 60 fps
        ours[frames] = motion["joints"][mine].reshape(-1, 33, 3)
        ours_cam = (ours @ R_est.T + t_est)[frames][:, BODY]
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
        world = tracks[0][role].world.reshape(FRAMES, 33, 3)[frames][:, BODY]
        good = agree[role][frames][:, BODY]
        lift_error, world_error = (
            np.linalg.norm(procrustes_align(points, ref_cam) - ref_cam, axis=-1) * 1000
            for points in (ours_cam, world)
        )
        lift_good, world_good = np.nanmean(lift_error[good]), np.nanmean(world_error[good])
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
    print(f"multiview_pa_mpjpe_mm: {np.mean(results):.1f} mm")


if __name__ == "__main__":
    main()
