"""Known statures set the lift's metric scale: the bodies, the camera's height, the distances."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import process_argv, query, run_cli
from test_lift_camera import standing_person

from tasks.lift.camera import (
    ANKLES,
    EARS,
    HIP_JOINTS,
    KNEES,
    SHOULDERS,
    STATURE_SHARE,
    fov_intrinsics,
    ground_fighters,
    look_at,
    project,
    read_qca,
    stature,
    stature_notes,
    stature_scales,
    write_calibration,
)

# The sample's two people, measured on the four calibrated views' triangulation
# (benchmarks/lift_multiview.py, "statures on the reference").
SAMPLE_STATURES = {"adversary": 1.668, "opponent": 1.386}


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


def scene(rng: np.random.Generator, blow_up: float) -> tuple[list, list[float]]:
    """Two people 1.6 m apart seen from 2.5 m up (as test_lift_camera's), their metric skeletons
    ``blow_up`` times too big (an average body on smaller people); each person's true stature."""
    K = fov_intrinsics(1920, 1080, 60.0)
    R, t = look_at(np.array([0.0, -6.0, 2.5]), np.array([0.0, 0.0, 1.0]))
    fighters, statures = [], []
    for x in (-0.8, 0.8):
        world = []
        for f in range(30):
            person = standing_person(rng, np.array([x + 0.1 * np.sin(f / 5), 0.2 * f / 30]))
            person[KNEES] = person[ANKLES] + [0.0, 0.0, 0.42]
            person[EARS] = person[SHOULDERS] + [[0.12, 0.0, 0.15], [-0.12, 0.0, 0.15]]
            world.append(person)
        world = np.array(world)
        hips = world[:, HIP_JOINTS].mean(1)
        landmarks = blow_up * (world - hips[:, None]) @ R.T
        uv = project(world, K, R, t) + rng.normal(0, 1.0, (30, 33, 2))
        fighters.append((uv, np.ones((30, 33)), landmarks))
        statures.append(stature(world))  # 1.69 m
    return fighters, statures


def test_known_statures_undo_a_wrong_body_size():
    fighters, statures = scene(np.random.default_rng(3), 1.15)
    K = fov_intrinsics(1920, 1080, 60.0)

    def camera_height(scales: list[float]) -> float:
        scaled = [(k, c, w * s) for (k, c, w), s in zip(fighters, scales, strict=True)]
        return float(ground_fighters(scaled, K, (1920, 1080))[0].centre[2])

    assert stature_scales(fighters, K, [None, None]) == [1.0, 1.0]
    assert camera_height([1.0, 1.0]) > 2.75  # the scene 15 % too big
    both = stature_scales(fighters, K, statures)
    np.testing.assert_allclose(both, 1 / 1.15, rtol=0.01)
    assert camera_height(both) == pytest.approx(2.5, abs=0.03)
    # One known: the other is scaled to stand on the floor the known one's feet define.
    one = stature_scales(fighters, K, [statures[0], None])
    np.testing.assert_allclose(one, 1 / 1.15, rtol=0.01)
    assert camera_height(one) == pytest.approx(2.5, abs=0.03)


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
    body puts the camera 28 cm too high; the people's statures (the multi-view reference's)
    take 17 cm of that off. Only the lift reruns: the statures are its settings.

    The issue asks for 5 cm; what is left is the man's posture, not his size. BlazePose's 3D has
    him more upright than the triangulation does (ankle-to-ear height over the straightened
    chain 0.93 against 0.88), so at his true stature his image fits a body 5 % further away:
    his feet alone put the camera at 2.03 m, the woman's at 1.88 m (benchmarks/lift_multiview.py,
    "adversary known" and "opponent known")."""
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
    assert abs(given - truth) < 0.15 and abs(given - truth) < 0.5 * (average - truth), (
        given,
        average,
        truth,
    )
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
