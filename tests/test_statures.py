"""Known statures set the lift's metric scale: the bodies, the camera's height, the distances."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import process_argv, query, run_cli
from test_lift_camera import standing_person

from tasks.lift.camera import (
    ANKLES,
    EARS,
    FOOT_POINTS,
    HIP_JOINTS,
    KNEES,
    SHOULDERS,
    STATURE_SHARE,
    camera_height,
    fov_intrinsics,
    ground_fighters,
    look_at,
    project,
    read_qca,
    stature,
    stature_notes,
    write_calibration,
)

# The sample's two people, measured on the four calibrated views' triangulation
# (benchmarks/lift_multiview.py, "statures on the reference").
SAMPLE_STATURES = {"adversary": 1.668, "opponent": 1.386}
OFF_CHAIN = np.setdiff1d(
    np.arange(33), np.r_[ANKLES, KNEES, HIP_JOINTS, SHOULDERS, EARS, FOOT_POINTS]
)


def upright_body(bend: float) -> np.ndarray:
    """(33, 3) a body's chain joints, ankles at 0.07 m and ears at 1.57 m when ``bend`` is 0;
    ``bend`` (radians) tilts the shins forward and the thighs back, as a crouch, and leans the
    trunk. The other joints are NaN."""
    points = np.full((33, 3), np.nan)
    lengths = {"shin": 0.41, "thigh": 0.42, "trunk": 0.52, "neck": 0.15}
    for side, x in ((0, -0.1), (1, 0.1)):
        ankle = np.array([x, 0.0, 0.07])
        knee = ankle + lengths["shin"] * np.array([0.0, np.sin(bend), np.cos(bend)])
        hip = knee + lengths["thigh"] * np.array([0.0, -np.sin(bend), np.cos(bend)])
        points[ANKLES[side]], points[KNEES[side]], points[HIP_JOINTS[side]] = ankle, knee, hip
        shoulder = hip + lengths["trunk"] * np.array([0.1 * x, np.sin(bend), np.cos(bend)])
        points[SHOULDERS[side]] = shoulder
        points[EARS[side]] = shoulder + [-0.5 * x, 0.0, lengths["neck"]]
    return points


def test_stature_is_the_standing_height_whatever_the_pose():
    standing = upright_body(0.0)[None]
    ears_over_ankles = 1.57 - 0.07
    assert stature(standing) == pytest.approx(ears_over_ankles / STATURE_SHARE, abs=0.005)
    crouched = np.stack([upright_body(bend) for bend in np.linspace(0.0, 0.6, 20)])
    assert stature(crouched) == pytest.approx(stature(standing), abs=0.005)
    with pytest.raises(ValueError, match="neck"):
        stature(np.where(np.isin(np.arange(33), EARS)[None, :, None], np.nan, standing))


def scene(
    rng: np.random.Generator, blow_up: float, limbs: float = 1.0
) -> tuple[list, list[float], list[np.ndarray]]:
    """Two people 1.6 m apart seen from 2.5 m up (as test_lift_camera's), their metric skeletons
    ``blow_up`` times too big (an average body on smaller people) and their joints off the
    ankle-to-ear chain and the feet (head, arms, hands) ``limbs`` times too far from the hips;
    each person's true stature and true hip centres (F, 3)."""
    K = fov_intrinsics(1920, 1080, 60.0)
    R, t = look_at(np.array([0.0, -6.0, 2.5]), np.array([0.0, 0.0, 1.0]))
    fighters, statures, hips = [], [], []
    for x in (-0.8, 0.8):
        world = []
        for f in range(30):
            person = standing_person(rng, np.array([x + 0.1 * np.sin(f / 5), 0.2 * f / 30]))
            person[KNEES] = person[ANKLES] + [0.0, 0.0, 0.42]
            person[EARS] = person[SHOULDERS] + [[0.12, 0.0, 0.15], [-0.12, 0.0, 0.15]]
            world.append(person)
        world = np.array(world)
        centre = world[:, HIP_JOINTS].mean(1)
        about = world - centre[:, None]
        about[:, OFF_CHAIN] *= limbs
        landmarks = blow_up * about @ R.T
        uv = project(world, K, R, t) + rng.normal(0, 1.0, (30, 33, 2))
        fighters.append((uv, np.ones((30, 33)), landmarks))
        statures.append(stature(world))  # 1.69 m
        hips.append(centre)
    return fighters, statures, hips


def test_known_statures_undo_a_wrong_body_size():
    fighters, statures, _ = scene(np.random.default_rng(3), 1.15)
    K = fov_intrinsics(1920, 1080, 60.0)

    def grounded(known: list[float | None]) -> tuple[float, list[float]]:
        camera, _, scales = ground_fighters(fighters, K, (1920, 1080), known)
        return float(camera.centre[2]), scales

    height, scales = grounded([None, None])
    assert scales == [1.0, 1.0] and height > 2.75  # the scene 15 % too big
    height, scales = grounded(statures)
    np.testing.assert_allclose(scales, 1 / 1.15, rtol=0.01)
    assert height == pytest.approx(2.5, abs=0.03)
    # One known: the other is scaled to stand on the floor the known one's size sets.
    height, scales = grounded([statures[0], None])
    np.testing.assert_allclose(scales, 1 / 1.15, rtol=0.01)
    assert height == pytest.approx(2.5, abs=0.03)


def test_a_body_of_the_wrong_build_at_its_true_stature_still_finds_the_floor():
    """BlazePose's 3D has an average body's build: skeletons of the right height whose arms and
    head reach 20 % too far fit the image only further away, so their feet (the floor without
    statures) put the camera too high. The height from the statures comes from the ankles and
    ears alone."""
    fighters, statures, hips = scene(np.random.default_rng(5), 1.0, limbs=1.2)
    K = fov_intrinsics(1920, 1080, 60.0)
    R, t = look_at(np.array([0.0, -6.0, 2.5]), np.array([0.0, 0.0, 1.0]))

    def misplaced(camera, roots: list[np.ndarray]) -> float:
        """The median distance of the hip centres from the truth, in the camera's frame."""
        off = [
            (found @ camera.R.T + camera.t) - (truth @ R.T + t)
            for found, truth in zip(roots, hips, strict=True)
        ]
        return float(np.median(np.linalg.norm(np.concatenate(off), axis=1)))

    camera, roots, _ = ground_fighters(fighters, K, (1920, 1080))
    assert camera.centre[2] - 2.5 > 0.1
    unknown = misplaced(camera, roots)
    camera, roots, scales = ground_fighters(fighters, K, (1920, 1080), statures)
    assert camera.centre[2] == pytest.approx(2.5, abs=0.03)
    np.testing.assert_allclose(scales, 1.0, atol=0.01)  # their size kept, their place moved
    assert misplaced(camera, roots) < 0.5 * unknown, (misplaced(camera, roots), unknown)


def test_the_camera_height_needs_a_fighter_seen_head_to_foot():
    fighters, statures, _ = scene(np.random.default_rng(6), 1.0)
    K = fov_intrinsics(1920, 1080, 60.0)
    up = np.array([0.0, -1.0, 0.0])
    blind = [(k, np.where(np.isin(np.arange(33), EARS), 0.0, c), w) for k, c, w in fighters]
    assert camera_height(blind, K, up, 2.0) is None
    # Unknown to the metrology, the known fighter's own feet set the floor instead.
    camera, _, _ = ground_fighters(blind, K, (1920, 1080), statures)
    assert camera.centre[2] == pytest.approx(2.5, abs=0.08)


def test_a_fighter_scaled_from_the_other_s_height_is_told():
    body = upright_body(0.0)[None]
    (note,) = stature_notes(
        {"adversary": 1.8, "opponent": None}, {"adversary": body, "opponent": body}
    )
    assert "opponent's height is unknown" in note and f"{stature(body):.2f} m tall" in note
    assert stature_notes({"adversary": None, "opponent": None}, {"adversary": body}) == []
    assert stature_notes({"adversary": 1.8, "opponent": 1.7}, {"adversary": body}) == []


def test_the_sample_s_statures_bring_the_camera_down_to_the_calibrated_height(
    assets, sample_video, tmp_path, capsys
):
    """Camera 1 of the four-camera sample, lifted with its calibrated intrinsics: the average
    body puts the camera 28 cm too high; given the people's statures (the multi-view
    reference's) it is within 5 cm of the calibration (-0.4 cm in benchmarks/lift_multiview.py,
    which also gives each person's alone: +4.9 and -4.0 cm). Only the lift reruns: the
    statures are its settings."""
    cam01 = read_qca(assets / "samples" / "multi_person" / "Calib.qca.txt")[0][1]
    calibration = tmp_path / "cam01.json"
    write_calibration(calibration, cam01.K, cam01.dist, cam01.size, 0.0)
    data = tmp_path / "data"
    argv = process_argv(data, sample_video, "--lift-calibration", str(calibration), until="lift")
    known = ["--adversary-height", str(SAMPLE_STATURES["adversary"])]
    known += ["--opponent-height", str(SAMPLE_STATURES["opponent"])]
    for more in ([], known):
        code, _, err = run_cli(capsys, *argv, *more)
        assert code == 0, err
    heights = query(
        data,
        "SELECT c.height_m FROM lift_cameras c JOIN stage_outputs o "
        "ON o.stage = 'lift' AND o.key = c.key ORDER BY o.created_at",
    )
    assert len(heights) == 2
    (average,), (given,) = heights
    truth = float(cam01.centre[2])
    assert average - truth > 0.2, (average, truth)
    assert abs(given - truth) < 0.05, (given, average, truth)
    outputs = dict(query(data, "SELECT stage, count(*) FROM stage_outputs GROUP BY stage"))
    assert (outputs["ingest"], outputs["pose"], outputs["lift"]) == (1, 1, 2)


@pytest.mark.parametrize(
    "flag, value",
    [("--adversary-height", "-1.75"), ("--opponent-height", "4"), ("--opponent-height", "172")],
)
def test_a_bad_stature_is_refused_in_one_line(sample_video, tmp_path, capsys, flag, value):
    code, _, err = run_cli(capsys, *process_argv(tmp_path / "data", sample_video, flag, value))
    assert code != 0
    (line,) = err.strip().splitlines()
    assert "height_m" in line and "metres" in line and value.lstrip("-") in line
