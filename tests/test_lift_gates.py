"""Plausibility gates of the lift: what no boxer can do is dropped, counted and named."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from models.humanoid.boxer import BoneLengths
from tasks.errors import BadInput
from tasks.lift.camera import write_calibration
from tasks.lift.config import LiftStageConfig
from tasks.lift.gates import (
    GateConfig,
    depth_jumps,
    floating,
    notes,
    one_person,
    shot_problem,
    too_far,
    too_fast,
)
from tasks.lift.metrics import HIPS
from tasks.lift.resample import resample
from tasks.lift.series import cleanup_series, motion_columns
from tasks.lift.stage import FighterTrack, lift_video
from tasks.lift.synthetic import evaluate_lift, make_case

GATES = GateConfig()


def test_frame_gates():
    roots = np.zeros((6, 3))
    roots[:, 0] = np.arange(6) * 0.1  # 3 m/s at 30 fps
    roots[3, 0] += 1.0  # one frame 1 m off: 30 m/s into it and out of it
    roots[5] = np.nan  # a gap is not a jump
    np.testing.assert_array_equal(too_fast(roots, 30.0, GATES), [0, 0, 1, 1, 1, 0])
    camera = np.array([0.0, -30.0, 3.0])
    far = roots + [0.0, -50.0, 0.0]
    far[5] = np.nan
    assert not too_far(roots, camera, GATES).any()
    np.testing.assert_array_equal(too_far(far, np.zeros(3), GATES), [1, 1, 1, 1, 1, 0])
    np.testing.assert_array_equal(floating(np.array([0.0, 0.6, 1.2]), GATES), [0, 0, 1])
    # Placements 300, 60, 7, 3.1, 3.0, 2.9 m away: the first four frames jump in depth.
    placed = np.array([[0.0, 0.0, d] for d in (300.0, 60.0, 7.0, 3.1, 3.0, 2.9)])
    np.testing.assert_array_equal(depth_jumps(placed, GATES), [1, 1, 1, 1, 0, 0])


def test_one_person_gate():
    body = np.random.default_rng(0).uniform(0, 300, (4, 33, 2))
    beside = body + [200.0, 0.0]
    beside[1] = body[1] + 3.0
    beside[2] = np.nan  # unseen: not flagged
    np.testing.assert_array_equal(one_person(body, beside, GATES), [0, 1, 0, 0])


def test_shot_gate_names_the_problem():
    assert shot_problem(2.0, 1.5, GATES) is None
    assert shot_problem(2.0, None, GATES) is None
    assert "16.3 m above the floor" in shot_problem(16.3, 1.5, GATES)
    assert "17.6 m apart" in shot_problem(2.0, 17.6, GATES)
    assert shot_problem(float("nan"), 1.5, GATES) is not None


def test_notes_name_reasons_that_drop_a_notable_share():
    lines = notes({"depth": 3, "speed": 1, "floating": 0}, 40, GATES)
    assert lines == ["3 of 40 fighter-frames (8%) dropped as implausible: depth (see lift.gates)"]
    assert notes({"depth": 0}, 0, GATES) == []
    with pytest.raises(ValueError, match="max_depth_m must be a positive number"):
        GateConfig(max_depth_m=0)


def test_a_person_emerging_far_off_is_refused_not_lifted(assets, tmp_path):
    """Track ends are where a monocular lift blows up: a person coming out from behind an
    occluder is seen small for a few frames, which puts him tens of metres away. Without the
    gates those frames also bend the floor and the lift of every other frame (measured: MPJPE
    4.2 m, PA-MPJPE 458 mm, jitter 4,556 m/s^2 over the whole clip); with them the frames are
    dropped and the rest is lifted as if they had never been there."""
    case = make_case("walk", 0, assets)
    keypoints = case.inputs.keypoints_2d.copy()
    hips = keypoints[:, list(HIPS)].mean(1, keepdims=True)
    for frame, scale in enumerate((0.01, 0.05, 0.3)):  # 100x, 20x and 3x too small
        keypoints[frame] = hips[frame] + (keypoints[frame] - hips[frame]) * scale
    bad = dataclasses.replace(case, inputs=dataclasses.replace(case.inputs, keypoints_2d=keypoints))
    m = evaluate_lift(bad, LiftStageConfig(), tmp_path)
    frames = len(case.points)
    assert 3 <= m["frames_rejected"] <= 5
    assert m["frames_rejected_depth"] >= 1 and m["frames_rejected_speed"] >= 1
    assert m["adversary_frames_lifted"] == frames - m["frames_rejected"]
    assert m["output_pa_mpjpe_mm"] < 40 and m["output_mpjpe_mm"] < 60
    assert m["jitter_m_s2"] < 100
    off = dataclasses.replace(
        LiftStageConfig(),
        gates=GateConfig(max_depth_m=1e9, max_depth_ratio=1e9, max_root_speed_m_s=1e9),
    )
    ungated = evaluate_lift(bad, off, tmp_path)
    assert ungated["frames_rejected"] == 0 and ungated["output_mpjpe_mm"] > 1000


def test_one_person_tracked_as_both_fighters_is_refused(assets, tmp_path):
    """In a crowd the pose stage once put both roles on one woman for 170 frames. Here the
    opponent is a second walker 1/5 of the image to the side, except for 16 frames where his
    track jumps onto the adversary: those frames are dropped for both, counted and noted."""
    case = make_case("walk", 0, assets)
    inputs = case.inputs
    shifted = inputs.keypoints_2d + [case.size[0] / 5, 0.0]
    shifted[10:26] = inputs.keypoints_2d[10:26] + 1.0  # one pixel off: the same body
    calibration = tmp_path / "calibration.json"
    write_calibration(calibration, case.K, np.zeros(5), case.size, 0.0)
    frames = len(case.points)
    told: list[int] = []
    output = lift_video(
        {
            "adversary": FighterTrack(
                inputs.keypoints_2d, inputs.confidence, inputs.world_landmarks
            ),
            "opponent": FighterTrack(shifted, inputs.confidence, inputs.world_landmarks),
        },
        fps=case.fps,
        size=case.size,
        shots=[(0, 0, frames)],
        config=LiftStageConfig(),
        calibration=calibration,
        progress=told.append,
    )
    # The progress bar is told the shot's frames once its work is done.
    assert sum(told) == frames and told[-1] == frames
    m = output.metrics
    assert m["frames_rejected_one_person"] == 2 * 16
    assert m["adversary_frames_lifted"] == m["opponent_frames_lifted"] == frames - 16
    steps = output.motion["adversary"].step
    assert not set(range(10, 26)) & set(steps.tolist())
    assert any("dropped as implausible: one_person" in note for note in output.notes)


def test_a_fighter_whose_every_frame_was_dropped_leaves_no_rows():
    """The cleanup's gates can drop every frame of a fitted fighter (a small fighter's track on
    the other fighter's body, then floating): the lift failed with "cannot reshape array of
    size 0" where that fighter simply has no motion rows."""
    qpos = np.full((20, 35), np.nan)
    none = resample(
        qpos,
        np.full((20, 33, 3), np.nan),
        np.zeros((20, 2), bool),
        fps=60.0,
        rate=30.0,
        bones=BoneLengths(),
    )
    columns = motion_columns({"opponent": none}, cleanup_series({"opponent": none}))
    assert columns["joints"].shape == (0, 99) and len(columns["step"]) == 0


def test_when_the_gates_leave_every_shot_out_the_error_says_why(assets, tmp_path):
    """A fighter seen all clip long whose every shot a gate leaves out: the error names the
    gate and the shot, not "no fighter is seen" (which sent a reader looking for the person)."""
    case = make_case("walk", 0, assets)  # its camera is 1.48 m high
    low = dataclasses.replace(LiftStageConfig(), gates=GateConfig(max_camera_height_m=0.5))
    with pytest.raises(BadInput) as refused:
        evaluate_lift(case, low, tmp_path)
    assert str(refused.value).startswith("lift: no shot could be lifted: shot 0 left out: ")
    assert "lift.gates.max_camera_height_m is 0.5" in str(refused.value)
