"""Flat frames and fades at the cut detector, and videos refused early for what later stages
need (issue 33's smaller items)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import process_argv, read_video, run_cli, write_video
from fades import fade_gains, faded
from test_cli import db_snapshot

from tasks.ingest.config import IngestConfig
from tasks.ingest.probe import scan_video

MULTI = Path("samples/multi_person")


def shrunk(path: Path, size: tuple[int, int] = (272, 480), frames: int = 100) -> list:
    """The first ``frames`` frames of ``path`` resized to ``size`` (width, height)."""
    return [cv2.resize(f, size, interpolation=cv2.INTER_AREA) for f in read_video(path)[1][:frames]]


def cuts(tmp_path: Path, name: str, frames: list[np.ndarray]) -> list[int]:
    video = write_video(tmp_path / f"{name}.mp4", frames)
    return [shot.start for shot in scan_video(video, IngestConfig()).shots[1:]]


def test_fade_gains_go_to_black_and_back():
    gains = fade_gains(70, 38, 10)
    assert np.allclose(gains[:38], 1) and np.allclose(gains[62:], 1)
    assert gains[38] == pytest.approx(0.9) and np.all(gains[47:52] == 0)
    assert gains[52] == pytest.approx(0.1) and gains[61] == pytest.approx(1.0)


@pytest.mark.parametrize("grey", [0, 30, 128, 255])
def test_flat_frames_are_no_cut(tmp_path: Path, grey: int):
    # A flat frame's grey thumbnail is all zeros: it used to read as "unrelated" to the next one,
    # a cut every ingest.min_shot_frames.
    assert cuts(tmp_path, "flat", [np.full((96, 128, 3), grey, np.uint8)] * 60) == []


def test_fades_within_a_shot_are_no_cut(assets: Path, tmp_path: Path):
    frames = shrunk(assets / MULTI / "cam01.mp4")
    assert cuts(tmp_path, "whole", frames) == []
    for length in (3, 10, 30):  # to black and back, black at frames 47-51
        assert (
            cuts(tmp_path, f"fade{length}", faded(frames, fade_gains(100, 48 - length, length)))
            == []
        )
    slow = 1 - 0.95 * np.sin(np.linspace(0, np.pi, 100))  # down to 5 % and back, never black
    assert cuts(tmp_path, "slow", faded(frames, slow)) == []


@pytest.mark.parametrize("length", [3, 10, 30])
def test_a_fade_from_one_shot_into_another_is_one_cut(assets: Path, tmp_path: Path, length: int):
    """cam01 fades to black (frames 47-51), cam02 fades in from frame 52: one cut, from the first
    black frame up to the frame where cam02 is back at half its brightness."""
    a, b = shrunk(assets / MULTI / "cam01.mp4"), shrunk(assets / MULTI / "cam02.mp4")
    found = cuts(tmp_path, "fade", faded(a[:52] + b[52:], fade_gains(100, 48 - length, length)))
    assert len(found) == 1 and 47 <= found[0] <= 52 + length // 2, found


def test_a_video_shorter_than_a_clip_is_refused_before_the_stages_run(
    assets: Path, tmp_path: Path, capsys
):
    """Half a second of the sample (30 frames at 60 fps) goes through pose; asked for a dataset,
    whose shortest clip is 1 s, it is refused at once in one line and nothing is written."""
    video = write_video(
        tmp_path / "short.mp4", shrunk(assets / MULTI / "cam01.mp4", (544, 960), 30), fps=60.0
    )
    data = tmp_path / "data"
    code, _, err = run_cli(capsys, *process_argv(data, video, until="pose"))
    assert code == 0, err
    before = db_snapshot(data / "ringside.duckdb")
    code, out, err = run_cli(capsys, *process_argv(data, video))
    assert code != 0 and out == ""
    assert err.count("\n") == 1 and err.startswith(f"ringside: error: {video}"), err
    assert "lasts 0.50 s (30 frames at 60 fps)" in err and "dataset.min_clip_s" in err, err
    assert db_snapshot(data / "ringside.duckdb") == before
