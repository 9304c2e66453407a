"""The lift stage: synthetic ground truth, the real two-person sample, bad input."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import (
    dropped_frames_copy,
    process_argv,
    query,
    read_video,
    run_cli,
    write_video,
)
from test_lift_series import colour_pixels

from storage.artifacts import artifact_path
from storage.db import connect
from tasks.errors import BadInput
from tasks.lift.config import LiftStageConfig
from tasks.lift.stage import FighterTrack, lift_video
from tasks.lift.store import lift_series
from tasks.lift.synthetic import evaluate_lift, make_case


def lift_metrics(data: Path) -> dict[str, float]:
    return dict(
        query(
            data,
            "SELECT m.name, m.value FROM stage_metrics m "
            "JOIN stage_outputs o USING (stage, video_id, key) WHERE m.stage = 'lift' "
            "QUALIFY row_number() OVER (PARTITION BY m.name ORDER BY o.created_at DESC) = 1",
        )
    )


@pytest.mark.parametrize("clip", ["punch", "walk"])
def test_synthetic_truth_is_recovered(clip, assets, tmp_path):
    case = make_case(clip, 0, assets)
    m = evaluate_lift(case, LiftStageConfig(), tmp_path)
    assert 40 < m["input_pa_mpjpe_mm"] < 60  # the BlazePose-like noise the lift starts from
    assert m["output_pa_mpjpe_mm"] < 40
    assert m["output_pa_mpjpe_mm"] <= 0.7 * m["input_pa_mpjpe_mm"]
    assert m["output_mpjpe_mm"] < m["input_mpjpe_mm"]
    assert m["floor_penetration_max_mm"] < 10 and m["bone_length_std_mm"] < 5
    # Foot skating is checked on the real sample below: here the floor the stage finds for one
    # lone fighter is tilted by several degrees, which hides most contacts (see issue notes).


def latest_key(data: Path) -> str:
    """The newest lift output's key (other tests may add outputs to the shared run)."""
    sql = "SELECT key FROM stage_outputs WHERE stage = 'lift' ORDER BY created_at DESC LIMIT 1"
    return query(data, sql)[0][0]


def test_sample_after_cleanup(sample_run: Path):
    m = lift_metrics(sample_run)
    key = latest_key(sample_run)
    assert m["floor_penetration_max_mm"] < 10
    assert m["inter_fighter_penetration_max_mm"] < 10
    for role in ("adversary", "opponent"):
        # On the floor while standing: the sample's adversary was lifted 31 cm up in the air.
        assert m[f"{role}_foot_height_median_cm"] < 2.0
        assert (
            m[f"{role}_contact_slide_cm_per_frame"] < m[f"{role}_contact_slide_cm_per_frame_before"]
        )
    # Height-weighted skating counts feet on the floor fully, so pinning feet that hovered a
    # few cm can raise it slightly (measured 0.06 cm/frame before and after): it stays small.
    assert m["foot_skating_cm_per_frame"] < 0.1
    assert m["bone_length_std_mm"] < 5
    assert 0.5 < m["fighter_distance_mean_m"] < 3.0
    # 100 frames at 60 fps are 1.65 s: steps 0..49 at 30 Hz.
    rows = query(
        sample_run,
        "SELECT role, count(*), min(step), max(time_s) FROM lift_motion WHERE key = ? "
        "GROUP BY role ORDER BY role",
        [key],
    )
    assert rows == [("adversary", 50, 0, 49 / 30), ("opponent", 50, 0, 49 / 30)]
    steps = query(
        sample_run,
        "SELECT qpos, qvel FROM lift_motion WHERE key = ? AND role = 'adversary' ORDER BY step",
        [key],
    )
    root = np.array([q[:3] for q, _ in steps])
    root_speed = np.array([v[:3] for _, v in steps])
    # qvel is on the 30 Hz grid: central differences of the root there.
    np.testing.assert_allclose((root[2:] - root[:-2]) * 15, root_speed[1:-1], atol=1e-3)
    qpos, joints = query(sample_run, "SELECT qpos, joints FROM lift_motion LIMIT 1")[0]
    assert np.linalg.norm(qpos[3:7]) == pytest.approx(1.0, abs=1e-5)
    assert len(qpos) == 35 and np.isfinite(qpos).all() and np.isfinite(joints).all()
    # The camera: above the floor, looking down, as the phone that filmed the sample was.
    height, pitch = query(
        sample_run, "SELECT height_m, pitch_deg FROM lift_cameras WHERE key = ?", [key]
    )[0]
    assert 1.0 < height < 3.5 and 0 < pitch < 80


def test_review_video(sample_run: Path):
    """Both humanoids, one frame per 30 Hz step, as H.264 that browsers play."""
    key = latest_key(sample_run)
    (name,) = query(
        sample_run, "SELECT artifact FROM lift_media WHERE kind = 'video' AND key = ?", [key]
    )[0]
    assert name.endswith(".mp4")
    fourcc, frames = read_video(artifact_path(sample_run / "artifacts", name))
    steps = query(sample_run, "SELECT max(step) + 1 FROM lift_motion WHERE key = ?", [key])[0][0]
    assert fourcc in ("avc1", "h264") and len(frames) == steps == 50
    for frame in frames[::10]:
        red, blue = colour_pixels(frame)
        assert red > 100 and blue > 100  # the adversary's and the opponent's trunk and gloves
    assert query(sample_run, "SELECT DISTINCT kind FROM lift_media WHERE key = ?", [key]) == [
        ("video",)
    ]


def test_series_agree_with_the_summary(sample_run: Path):
    """The dashboard's per-step series aggregate to the stage's metrics, up to the resampling
    from the video's 60 fps to the 30 Hz grid."""
    key = latest_key(sample_run)
    m = lift_metrics(sample_run)
    with connect(sample_run / "ringside.duckdb", read_only=True) as con:
        (video_id,) = con.execute(
            "SELECT video_id FROM stage_outputs WHERE stage = 'lift' AND key = ?", [key]
        ).fetchone()
        series = lift_series(con, key, video_id)
    assert series.time_s.shape == (50,) and set(series.fighters) == {"adversary", "opponent"}
    assert np.nanmean(series.fighter_distance_m) == pytest.approx(
        m["fighter_distance_mean_m"], abs=0.02
    )
    for role, mine in series.fighters.items():
        sunk_mm = mine.floor_penetration_m * 1000
        assert sunk_mm.max() <= m[f"{role}_floor_penetration_max_mm"] + 1.0
        assert sunk_mm.mean() == pytest.approx(m[f"{role}_floor_penetration_mean_mm"], abs=1.0)
        slide = mine.contact_slide_m_s
        summary_m_s = m[f"{role}_contact_slide_cm_per_frame"] / 100 * 60  # the sample's 60 fps
        if np.isfinite(slide).any():
            assert np.nanmean(slide) == pytest.approx(summary_m_s, abs=0.01)
        else:  # no foot in contact: nothing skates
            assert summary_m_s == 0


def test_bad_calibration_is_one_line_and_writes_nothing(sample_run, sample_video, tmp_path, capsys):
    bad = tmp_path / "calib.json"
    bad.write_text("{ this is not json")
    before = query(sample_run, "SELECT count(*) FROM lift_motion")[0][0]
    code, _, err = run_cli(
        capsys,
        "--data",
        str(sample_run),
        "process",
        str(sample_video),
        "--adversary",
        "A",
        "--ingest-chunk-frames",
        "30",
        "--lift-calibration",
        str(bad),
    )
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and f"{bad}: is not a calibration file" in lines[0]
    assert query(sample_run, "SELECT count(*) FROM lift_motion")[0][0] == before


def test_too_few_frames_is_a_clear_error():
    frames = 40
    track = FighterTrack(
        np.full((frames, 33, 2), np.nan), np.zeros((frames, 33)), np.full((frames, 33, 3), np.nan)
    )
    track.world[:5] = 0.1  # seen in 5 frames only
    track.keypoints[:5] = 100.0
    with pytest.raises(BadInput, match="no fighter is seen in 10 frames of any shot"):
        lift_video(
            {"adversary": track},
            fps=30.0,
            size=(640, 480),
            shots=[(0, 0, frames)],
            config=LiftStageConfig(),
            calibration=None,
        )


def test_frames_without_the_fighter_are_bridged(assets, tmp_path):
    """NaN keypoints (the pose stage lost the fighter for 10 frames) are missing data, not
    numbers: the output stays finite and close to the truth."""
    case = make_case("punch", 0, assets)
    keypoints = case.inputs.keypoints_2d.copy()
    world = case.inputs.world_landmarks.copy()
    keypoints[20:30] = np.nan
    world[20:30] = np.nan
    keypoints[40, :11] = np.nan  # and a face lost for a frame
    inputs = dataclasses.replace(case.inputs, keypoints_2d=keypoints, world_landmarks=world)
    m = evaluate_lift(dataclasses.replace(case, inputs=inputs), LiftStageConfig(), tmp_path)
    assert m["adversary_frames_lifted"] == len(case.points)
    assert m["output_pa_mpjpe_mm"] < 40


def test_a_calibrated_lens_distortion_is_taken_out_before_the_lift(assets, tmp_path):
    """An action camera's barrel lens bends keypoints by tens of pixels towards the image's
    edges. The lift projects through a pinhole, so the calibration's distortion must come out
    of the keypoints first: then the fighter is lifted as from an ideal camera."""
    case = make_case("walk", 0, assets)
    dist = np.array([-0.45, 0.2, 0.0, 0.0, 0.0])
    pinhole = case.inputs.keypoints_2d
    rays = np.concatenate(
        [(pinhole - case.K[:2, 2]) / np.diag(case.K)[:2], np.ones((*pinhole.shape[:-1], 1))], -1
    )
    seen, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), case.K, dist)
    seen = seen.reshape(pinhole.shape)
    assert np.nanmax(np.linalg.norm(seen - pinhole, axis=-1)) > 25  # a strong lens
    bent = dataclasses.replace(case, inputs=dataclasses.replace(case.inputs, keypoints_2d=seen))
    ideal = evaluate_lift(case, LiftStageConfig(), tmp_path)
    corrected = evaluate_lift(bent, LiftStageConfig(), tmp_path, dist=dist)
    ignored = evaluate_lift(bent, LiftStageConfig(), tmp_path)
    # Measured: placement 77.8 mm from a pinhole camera, 77.9 corrected, 127.0 ignored.
    assert abs(corrected["placement_error_mm"] - ideal["placement_error_mm"]) < 2
    for name in ("output_mpjpe_mm", "output_pa_mpjpe_mm"):
        assert abs(corrected[name] - ideal[name]) < 0.5, name
    assert ignored["placement_error_mm"] > ideal["placement_error_mm"] + 30


def _walking_speeds(data: Path, video_id: str) -> dict[str, tuple[float, float]]:
    """Per fighter, the pelvis's net horizontal speed (m/s: distance from the first to the last
    frame over the time between) before and after 50/60 s, in the video's newest lift (a
    shared data directory may hold reruns). Net, not the length of the path: the opponent
    barely moves (0.15 m/s net), and the path of a body standing nearly still measures its
    sway and the lift's jitter, which a re-timing may change by 40 %."""
    rows = query(
        data,
        "SELECT role, time_s, qpos[1], qpos[2] FROM lift_motion WHERE video_id = ? AND key = "
        "(SELECT key FROM stage_outputs WHERE stage = 'lift' AND video_id = ? "
        "ORDER BY created_at DESC LIMIT 1) ORDER BY role, step",
        [video_id, video_id],
    )
    speeds = {}
    for role in ("adversary", "opponent"):
        t, x, y = np.array([r[1:] for r in rows if r[0] == role]).T
        split = int(np.searchsorted(t, 50 / 60))
        parts = []
        for a, b in ((0, split), (split, len(t))):
            net = np.hypot(x[b - 1] - x[a], y[b - 1] - y[a])
            parts.append(net / (t[b - 1] - t[a]))
        speeds[role] = tuple(parts)
    return speeds


def test_a_camera_dropping_frames_moves_the_fighters_at_their_real_speed(
    sample_run, sample_video, tmp_path, capsys
):
    """The sample with one frame in three dropped from frame 50 on (each kept frame at its own
    time): lifted, the fighters walk as fast as in the sample before and after the drop, within
    0.1 m/s (measured: 0.02 at most; the adversary walks 0.6 m/s before and 0.48 after). Taken
    as a constant 42.3 fps, as OpenCV reports it, the adversary was 30 % too slow before the
    drop and 65 % too fast after it."""
    video = dropped_frames_copy(sample_video, tmp_path / "vfr.mp4", keep_from=50, every=3)
    data = tmp_path / "data"
    code, out, _ = run_cli(capsys, *process_argv(data, video, until="lift"))
    assert code == 0 and "variable frame rate (20 to 60 fps)" in out
    (video_id,) = query(data, "SELECT video_id FROM videos")[0]
    (sample_id,) = query(sample_run, "SELECT video_id FROM videos")[0]
    # One garbled frame (the first new picture after the dropped ones) once made the refinement
    # read every later frame as flipped: the adversary's arms swapped for 45 frames, and his
    # lift swung 1 m in depth.
    flips = query(
        data, "SELECT value FROM stage_metrics WHERE stage = 'pose' AND name = 'flips_fixed'"
    )
    assert flips == [(0.0,)]
    retimed, truth = _walking_speeds(data, video_id), _walking_speeds(sample_run, sample_id)
    for role in truth:
        assert np.allclose(retimed[role], truth[role], rtol=0, atol=0.1), (role, retimed, truth)


def test_a_fighter_stepping_out_from_behind_an_occluder_is_lifted_where_she_stands(
    sample_video, tmp_path, capsys
):
    """The sample with a grey pillar painted over the opponent for 40 frames, then sliding off
    (25 px a frame): she is seen from frame 48 on, the adversary from frame 0. Before, the
    cleanup filtered her over the whole shot with a stand-in parked 1 km away before she was
    seen: her first frame came out 214 m off, 40 of her 52 frames were dropped as too fast,
    the fighters stood 3.07 m apart and the dataset refused 2 steps. The adversary, his right
    side behind the pillar, may have a frame whose placement jumps (measured: one, at 1.9
    times his distance from the camera): it is dropped with its neighbours, and the dataset
    bridges the gap."""
    _, frames = read_video(sample_video)
    for i, frame in enumerate(frames):
        left = 560 + max(0, i - 40) * 25
        frame[350:, left:] = 90
    video = write_video(tmp_path / "pillar.mp4", frames, fps=60.0)
    data = tmp_path / "data"
    code, out, err = run_cli(capsys, *process_argv(data, video))
    # She is seen for 0.87 s, under dataset.min_clip_s: lifted, but no dataset to train on.
    assert code == 2 and "unusable: one fighter only" in err, err
    m = lift_metrics(data)
    assert m["frames_rejected"] <= 3 and "dropped as implausible" not in out
    assert m["adversary_frames_lifted"] >= 97 and m["opponent_frames_lifted"] >= 50
    assert 0.8 < m["fighter_distance_mean_m"] < 1.6, m["fighter_distance_mean_m"]
    speeds = query(
        data, "SELECT max(abs(qvel[1])), max(abs(qvel[2])) FROM lift_motion WHERE role = 'opponent'"
    )[0]
    assert max(speeds) < 3.0, speeds
    # No step refused by the dataset's guard either (before: 2). Her 0.87 s are shorter than a
    # clip (dataset.min_clip_s), so the adversary's clips are what the dataset holds.
    assert "left out as implausible" not in out
    assert query(data, "SELECT count(*) FROM dataset_transitions WHERE agent = 0")[0][0]
