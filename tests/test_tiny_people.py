"""A video whose people are too small to lift is refused saying so, with their measured height
in pixels, not that no fighter is seen (issue: "a video of tiny people fails with 'no fighter
is seen in 10 frames'")."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
from conftest import process_argv, read_video, run_cli, write_video

from tasks.lift.stage import MIN_PERSON_PX


def shrunk_onto_canvas(source: Path, path: Path, scale: float) -> Path:
    """``source`` with each frame shrunk by ``scale`` onto the middle of a grey canvas of the
    original size: the same people, far smaller in the same frame."""
    _, frames = read_video(source)
    height, width = frames[0].shape[:2]
    size = (round(width * scale), round(height * scale))
    y, x = (height - size[1]) // 2, (width - size[0]) // 2
    out = []
    for frame in frames:
        canvas = np.full_like(frame, 110)
        canvas[y : y + size[1], x : x + size[0]] = cv2.resize(
            frame, size, interpolation=cv2.INTER_AREA
        )
        out.append(canvas)
    return write_video(path, out, fps=60.0)


def test_people_too_small_to_lift_are_refused_with_their_height(
    sample_video: Path, tmp_path: Path, capsys
):
    """The sample's people (~820 px tall) shrunk by 0.12 to about 100 px: the pose stage finds
    both fighters, the lift leaves the shot out, and the one-line refusal gives their median
    height against the least that was lifted."""
    video = shrunk_onto_canvas(sample_video, tmp_path / "tiny.mp4", 0.12)
    code, out, err = run_cli(capsys, *process_argv(tmp_path / "data", video, until="lift"))
    assert code != 0
    assert err.count("\n") == 1 and err.startswith("ringside: error: lift: "), err
    assert "no fighter is seen" not in err
    found = re.search(r"the people found are a median (\d+) px tall, too small to lift", err)
    assert found, err
    assert 80 <= int(found[1]) < MIN_PERSON_PX, err
    assert f"people under about {MIN_PERSON_PX} px were not lifted" in err


def test_nobody_detected_keeps_the_old_refusal(sample_video: Path, tmp_path: Path, capsys):
    """Shrunk by 0.05 (people about 40 px tall) the person detector finds nobody: the pose
    stage's refusal is unchanged, and no height is claimed."""
    video = shrunk_onto_canvas(sample_video, tmp_path / "tinier.mp4", 0.05)
    code, out, err = run_cli(capsys, *process_argv(tmp_path / "data", video, until="lift"))
    assert code != 0
    assert err.count("\n") == 1, err
    assert err.startswith("ringside: error: pose: no fighters found in "), err
    assert "px" not in err
