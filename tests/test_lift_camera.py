"""Cameras and the world frame: intrinsics, .qca files, chessboards, triangulation, the floor."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from conftest import run_cli

from tasks.errors import BadInput
from tasks.lift.camera import (
    ANKLES,
    SHOULDERS,
    Camera,
    calibrate_chessboard,
    fov_intrinsics,
    ground_fighters,
    look_at,
    project,
    read_calibration,
    read_qca,
    root_translations,
    triangulate,
    world_from_floor,
)


def standing_person(rng: np.random.Generator, at: np.ndarray) -> np.ndarray:
    """(33, 3) world points of a 1.7 m tall stick person standing at ``at`` (feet on z = 0)."""
    points = rng.normal(0.0, 0.12, (33, 3))
    points[:, 2] = rng.uniform(0.1, 1.7, 33)
    points[ANKLES] = [[-0.1, 0.0, 0.08], [0.1, 0.0, 0.08]]
    points[[29, 30, 31, 32]] = [
        [-0.1, -0.05, 0.0],
        [0.1, -0.05, 0.0],
        [-0.1, 0.15, 0.0],
        [0.1, 0.15, 0.0],
    ]
    points[SHOULDERS] = [[-0.2, 0.0, 1.45], [0.2, 0.0, 1.45]]
    points[[23, 24]] = [[-0.12, 0.0, 0.95], [0.12, 0.0, 0.95]]
    return points + [at[0], at[1], 0.0]


def test_fov_intrinsics():
    K = fov_intrinsics(1920, 1080, 90.0)
    assert K[0, 0] == pytest.approx(960.0) and K[1, 1] == K[0, 0]
    assert (K[0, 2], K[1, 2]) == (960.0, 540.0)
    with pytest.raises(ValueError, match="fov_deg"):
        fov_intrinsics(1920, 1080, 180.0)


def test_root_translation_is_exact_without_noise():
    rng = np.random.default_rng(1)
    K = fov_intrinsics(1920, 1080, 60.0)
    skeleton = rng.normal(0.0, 0.4, (5, 33, 3))  # metric points about the hip, camera axes
    roots = np.array(
        [[0.3, 0.2, 4.0], [-0.5, 0.1, 6.0], [0.0, 0.0, 3.0], [1.0, 0.4, 8.0], [0.2, -0.3, 5.0]]
    )
    cam = skeleton + roots[:, None]
    uv = cam[..., :2] / cam[..., 2:] * K[0, 0] + K[:2, 2]
    found = root_translations(uv, np.ones((5, 33)), skeleton, K)
    np.testing.assert_allclose(found, roots, atol=1e-6)
    blind = root_translations(uv, np.zeros((5, 33)), skeleton, K)
    assert np.isnan(blind).all()


def test_two_people_give_the_camera_height_and_their_distance():
    rng = np.random.default_rng(2)
    K = fov_intrinsics(1920, 1080, 60.0)
    camera_at, target = np.array([0.0, -6.0, 2.5]), np.array([0.0, 0.0, 1.0])
    R, t = look_at(camera_at, target)
    fighters, truth_roots = [], []
    for x in (-0.8, 0.8):
        frames = [
            standing_person(rng, np.array([x + 0.1 * np.sin(f / 5), 0.2 * f / 30]))
            for f in range(30)
        ]
        world = np.array(frames)
        hips = world[:, [23, 24]].mean(1)
        landmarks = (world - hips[:, None]) @ R.T  # camera axes about the hip centre
        uv = project(world, K, R, t) + rng.normal(0, 1.0, (30, 33, 2))
        fighters.append((uv, np.ones((30, 33)), landmarks))
        truth_roots.append(hips)
    camera, roots, scales = ground_fighters(fighters, K, (1920, 1080))
    assert scales == [1.0, 1.0]
    assert camera.centre[2] == pytest.approx(2.5, abs=0.08)
    distance = np.linalg.norm(roots[0] - roots[1], axis=1)
    truth = np.linalg.norm(truth_roots[0] - truth_roots[1], axis=1)
    np.testing.assert_allclose(distance, truth, atol=0.08)
    for found in roots:
        assert np.median(found[:, 2]) == pytest.approx(0.95, abs=0.06)  # hip height


def test_world_from_floor_puts_the_floor_at_zero():
    normal = np.array([0.0, -0.8, -0.6])  # up, seen from a camera pitched down
    R, t = world_from_floor(normal, 2.0)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    floor_point = np.array([0.0, 1.0, 2.0 / 0.6 - 0.8 / 0.6])  # n @ p + 2 = 0
    assert normal @ floor_point + 2.0 == pytest.approx(0.0)
    assert ((floor_point - t) @ R)[2] == pytest.approx(0.0, abs=1e-9)
    assert (-R.T @ t)[2] == pytest.approx(2.0)  # camera height


def test_triangulation_from_four_cameras():
    rng = np.random.default_rng(4)
    K = fov_intrinsics(1920, 1080, 60.0)
    cams = []
    for angle in np.radians([0, 80, 170, 260]):
        R, t = look_at(
            np.array([5 * np.cos(angle), 5 * np.sin(angle), 2.0]), np.array([0.0, 0.0, 1.0])
        )
        cams.append(Camera(K, np.zeros(5), R, t, (1920, 1080)))
    points = rng.uniform(-0.5, 0.5, (10, 3)) + [0, 0, 1]
    uv = np.stack([project(points, c.K, c.R, c.t) for c in cams])
    weights = np.ones((4, 10))
    np.testing.assert_allclose(triangulate(uv, weights, cams), points, atol=1e-6)
    weights[1:, 0] = 0  # point 0 seen by one camera only
    assert np.isnan(triangulate(uv, weights, cams)[0]).all()


def test_chessboard_calibration_recovers_the_focal_length(tmp_path, capsys):
    board, square = (7, 5), 0.04
    K = fov_intrinsics(960, 720, 60.0)
    pattern = np.zeros((board[0] * board[1], 3))
    pattern[:, :2] = np.mgrid[: board[0], : board[1]].T.reshape(-1, 2) * square
    # Draw the board (8x6 squares) as seen from several poses.
    images, rng = [], np.random.default_rng(3)
    for _ in range(8):
        image = np.full((720, 960), 255, np.uint8)
        rvec = rng.normal(0.0, 0.3, 3)
        tvec = np.array([-0.12, -0.08, 0.55]) + rng.normal(0.0, 0.03, 3)
        for i in range(-1, board[0]):
            for j in range(-1, board[1]):
                if (i + j) % 2 == 0:
                    corners = (
                        np.array(
                            [[i, j, 0], [i + 1, j, 0], [i + 1, j + 1, 0], [i, j + 1, 0]], float
                        )
                        * square
                    )
                    uv, _ = cv2.projectPoints(corners, rvec, tvec, K, None)
                    cv2.fillConvexPoly(
                        image,
                        np.round(uv.reshape(-1, 2) * 16).astype(np.int32),
                        0,
                        cv2.LINE_AA,
                        shift=4,
                    )
        images.append(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    found, dist, rms = calibrate_chessboard(images, board=board, square_m=square)
    assert rms < 1.0
    assert found[0, 0] == pytest.approx(K[0, 0], rel=0.03)
    with pytest.raises(ValueError, match="at least 3 are needed"):
        calibrate_chessboard(images[:2], board=board, square_m=square)

    # The same through the command line, into a file the lift reads back.
    paths = []
    for i, image in enumerate(images):
        paths.append(tmp_path / f"board{i}.png")
        cv2.imwrite(str(paths[-1]), image)
    out = tmp_path / "calib.json"
    code, printed, _ = run_cli(
        capsys, "calibrate", *map(str, paths), "--board", "7x5", "--square", "0.04", "-o", str(out)
    )
    assert code == 0 and "rms=" in printed
    K_file, dist_file, size = read_calibration(out)
    np.testing.assert_allclose(K_file, found)
    assert size == (960, 720) and dist_file.shape == (5,)
    code, _, err = run_cli(
        capsys, "calibrate", str(paths[0]), "--board", "7by5", "--square", "0.04", "-o", str(out)
    )
    assert code == 2 and "--board: must look like 9x6" in err


def test_bad_calibration_files_are_named(tmp_path):
    broken = tmp_path / "calib.json"
    broken.write_text("{not json")
    with pytest.raises(BadInput, match="calib.json: is not a calibration file"):
        read_calibration(broken)
    broken.write_text('{"K": [[1, 0], [0, 1]], "dist": [0, 0, 0, 0, 0], "size": [10, 10]}')
    with pytest.raises(BadInput, match="3x3 K"):
        read_calibration(broken)
    with pytest.raises(BadInput, match="calibration file not found"):
        read_calibration(tmp_path / "missing.json")


def test_qca_cameras_of_the_sample(assets):
    cameras = read_qca(assets / "samples" / "multi_person" / "Calib.qca.txt")
    assert [name for name, _ in cameras] == ["cam01", "cam02", "cam03", "cam04"]
    for _, cam in cameras:
        np.testing.assert_allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-6)
        assert np.linalg.det(cam.R) == pytest.approx(1.0)
        assert 1.5 < cam.centre[2] < 2.5  # hung about 2 m above the floor
        assert cam.size == (1088, 1920) and cam.K[0, 0] == pytest.approx(1680, rel=0.01)
        # Each camera sees the middle of the room, in front of it and inside its image.
        uv, _ = cv2.projectPoints(
            np.array([[0.0, 0.0, 1.0]]), cv2.Rodrigues(cam.R)[0], cam.t, cam.K, cam.dist
        )
        assert (cam.R @ [0.0, 0.0, 1.0] + cam.t)[2] > 0
        assert 0 < uv[0, 0, 0] < 1088 and 0 < uv[0, 0, 1] < 1920


def test_bad_qca_file_is_named(tmp_path):
    broken = tmp_path / "Calib.qca.txt"
    broken.write_text("<calibration><cameras><camera serial='c'>")
    with pytest.raises(BadInput, match="Calib.qca.txt: is not a readable .qca"):
        read_qca(broken)
