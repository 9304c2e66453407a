from __future__ import annotations

from dataclasses import astuple
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import dropped_frames_copy, moving_box_frames, read_video, write_video

from storage.artifacts import artifact_name
from tasks.errors import BadInput
from tasks.ingest.config import IngestConfig, declare, parse_colour
from tasks.ingest.probe import (
    Shot,
    check_file,
    find_cuts,
    histogram_distance,
    hs_histogram,
    identify,
    plan_chunks,
    scan_video,
)
from tasks.ingest.stage import ingest_video
from tasks.ingest.store import AdversaryRow
from tasks.pose.frames import read_frames


def test_find_cuts_threshold_and_minimum_shot():
    d = np.zeros(40)
    d[[5, 7, 20, 39]] = [0.9, 0.8, 0.6, 0.3]
    # 7 is too close to the cut at 5; 39 is below the threshold.
    assert find_cuts(d, threshold=0.5, min_shot_frames=4) == [5, 20]
    assert find_cuts(d, threshold=0.5, min_shot_frames=1) == [5, 7, 20]
    assert find_cuts(d, threshold=0.95, min_shot_frames=1) == []


def test_plan_chunks_never_cross_a_cut():
    shots = [Shot(0, 0, 250, None, b""), Shot(1, 250, 260, 0.9, b""), Shot(2, 260, 700, 0.8, b"")]
    chunks = plan_chunks(shots, chunk_frames=200)
    assert [(c.shot, c.start, c.end) for c in chunks] == [
        (0, 0, 200),
        (0, 200, 250),
        (1, 250, 260),
        (2, 260, 460),
        (2, 460, 660),
        (2, 660, 700),
    ]
    assert [c.index for c in chunks] == list(range(6))


def test_histogram_distance_bounds():
    blue = np.full((40, 60, 3), (200, 60, 20), np.uint8)
    red = np.full((40, 60, 3), (20, 40, 210), np.uint8)
    hb, hr = hs_histogram(blue, 32), hs_histogram(red, 32)
    assert hb.sum() == pytest.approx(1.0)
    assert histogram_distance(hb, hb) == pytest.approx(0.0, abs=1e-6)
    assert histogram_distance(hb, hr) == pytest.approx(1.0, abs=1e-6)


def test_scan_finds_the_one_cut(two_shot_video: Path):
    scan = scan_video(two_shot_video, IngestConfig())
    assert scan.probe.frames == 60 == scan.probe.frames_declared
    assert scan.probe.fps == pytest.approx(30.0)
    assert (scan.probe.width, scan.probe.height) == (128, 96)
    assert [(s.start, s.end) for s in scan.shots] == [(0, 30), (30, 60)]
    assert scan.shots[1].cut_distance > IngestConfig().cut_threshold
    still = cv2.imdecode(np.frombuffer(scan.shots[1].thumbnail, np.uint8), cv2.IMREAD_COLOR)
    assert still.shape[1] == IngestConfig().thumbnail_width
    assert still[5, 5, 2] > 150 > still[5, 5, 0]  # the second shot's still is the red scene


def test_motion_alone_is_not_a_cut(tmp_path: Path):
    video = write_video(tmp_path / "one.mp4", moving_box_frames(60, (200, 60, 20)))
    scan = scan_video(video, IngestConfig())
    assert len(scan.shots) == 1
    assert scan.distances.max() < IngestConfig().cut_threshold


def test_sample_video_probe(sample_video: Path):
    scan = scan_video(sample_video, IngestConfig())
    assert (scan.probe.frames, scan.probe.fps, scan.probe.codec) == (100, 60.0, "h264")
    assert (scan.probe.width, scan.probe.height) == (1088, 1920)
    assert len(scan.shots) == 1


def test_ingest_output_rows(two_shot_video: Path):
    video = identify(two_shot_video)
    config = IngestConfig(chunk_frames=20)
    out = ingest_video(video, declare("Smith", "red"), config)
    assert [astuple(r) for r in out.rows["ingest_chunks"]] == [
        (0, 0, 0, 20),
        (1, 0, 20, 30),
        (2, 1, 30, 50),
        (3, 1, 50, 60),
    ]
    assert out.rows["ingest_adversaries"] == [AdversaryRow("Smith", "#c81e1e", None)]
    assert out.metrics["shot_cuts"] == 1 and out.metrics["chunks"] == 4
    # The thumbnails are the files the runner stores, each named for its bytes.
    assert sorted(out.files) == sorted(shot.thumbnail for shot in out.rows["ingest_shots"])
    for name, png in out.files.items():
        assert png[:4] == b"\x89PNG" and artifact_name(png, ".png") == name


def test_identity_is_the_bytes(two_shot_video: Path, tmp_path: Path):
    copy = tmp_path / "renamed.mp4"
    copy.write_bytes(two_shot_video.read_bytes())
    assert identify(copy).video_id == identify(two_shot_video).video_id


def test_check_file_names_the_problem(tmp_path: Path):
    (tmp_path / "empty.mp4").touch()
    cases = {
        tmp_path / "nope.mp4": "no such file",
        tmp_path: "is a directory",
        tmp_path / "empty.mp4": "is empty",
    }
    for path, problem in cases.items():
        with pytest.raises(BadInput, match=problem) as error:
            check_file(path)
        assert str(error.value).startswith(str(path))


def test_colours_and_declarations():
    assert parse_colour("Red") == "#c81e1e"
    assert parse_colour("#00FF00") == "#00ff00"
    with pytest.raises(BadInput, match="unknown colour 'redd'"):
        parse_colour("redd")
    with pytest.raises(BadInput, match="needs a name"):
        declare("  ")


@pytest.mark.parametrize(
    "field, value", [("cut_threshold", 0.0), ("chunk_frames", 0), ("truncation_tolerance", 1.0)]
)
def test_config_rejects_nonsense(field: str, value):
    with pytest.raises(ValueError, match=f"ingest.{field}"):
        IngestConfig(**{field: value})


@pytest.mark.parametrize("view", ["mirrored", "reframed"])
def test_a_cut_to_a_view_of_the_same_colours_is_found(sample_video: Path, tmp_path: Path, view):
    """The sample, cut at frame 50 to its mirror image or to a 2x crop of its centre: the colour
    histograms barely change (that cut was missed before: 0 shot cuts), the picture does."""
    capture = cv2.VideoCapture(str(sample_video))
    frames = []
    while len(frames) < 100:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(cv2.resize(frame, (272, 480), interpolation=cv2.INTER_AREA))
    capture.release()
    h, w = frames[0].shape[:2]
    if view == "mirrored":
        after = [cv2.flip(f, 1) for f in frames[50:]]
    else:
        after = [
            cv2.resize(f[h // 4 : 3 * h // 4, w // 4 : 3 * w // 4], (w, h)) for f in frames[50:]
        ]
    scan = scan_video(write_video(tmp_path / "cut.mp4", frames[:50] + after), IngestConfig())
    assert [(s.start, s.end) for s in scan.shots] == [(0, 50), (50, 100)]
    if view == "mirrored":
        assert scan.distances[50] < IngestConfig().cut_threshold  # the colours alone miss it
    whole = scan_video(write_video(tmp_path / "whole.mp4", frames), IngestConfig())
    assert len(whole.shots) == 1


def test_a_camera_dropping_frames_is_retimed_by_its_timestamps(sample_video: Path, tmp_path: Path):
    """The sample (60 fps) with one frame in three dropped from frame 50 on, each kept frame at
    its own time: a variable-rate file OpenCV calls 42.3 fps (67 frames over 1.58 s). Ingest
    puts it back on the 60 fps grid, each grid frame showing the frame on screen then, so later
    stages' times are real."""
    video = dropped_frames_copy(sample_video, tmp_path / "vfr.mp4", keep_from=50, every=3)
    assert cv2.VideoCapture(str(video)).get(cv2.CAP_PROP_FPS) == pytest.approx(42.3, abs=0.1)
    probe = scan_video(video, IngestConfig()).probe
    assert probe.fps == pytest.approx(60.0) and probe.frames_decoded == 67
    assert probe.frames == 99 and probe.duration_s == pytest.approx(1.65)
    kept = [*range(50), *range(50, 100, 3)]
    shown = [max(k for k in kept if k <= frame) for frame in range(probe.frames)]
    assert [kept[i] for i in probe.source_frames] == shown

    _, original = read_video(sample_video)
    grid = [frame for _, frame in read_frames(video, 0, probe.frames, probe.source_frames)]
    error = [np.abs(grid[i].astype(int) - original[shown[i]]).mean() for i in range(len(grid))]
    assert max(error) < 1.5  # the same pictures, H.264 twice
    # A chunk read from the middle lands on the same frames.
    assert all(
        np.array_equal(frame, grid[i])
        for i, frame in read_frames(video, 60, 75, probe.source_frames[60:75])
    )

    output = ingest_video(identify(video), declare("A"), IngestConfig())
    assert output.metrics["variable_frame_rate"] == 1.0 and output.metrics["fps"] == 60.0
    assert output.metrics["frames"] == 99 and output.metrics["frames_decoded"] == 67
    assert output.notes == (
        "variable frame rate (20 to 60 fps): re-timed by the container's timestamps to 60 fps, "
        "67 decoded frames on 99 grid frames (32 show the frame before again)",
    )


def test_even_frame_intervals_are_kept_as_they_are(sample_video: Path, tmp_path: Path):
    probe = scan_video(sample_video, IngestConfig()).probe
    assert probe.source_frames is None and probe.frames == probe.frames_decoded == 100
