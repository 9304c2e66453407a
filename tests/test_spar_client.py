"""examples/spar_client.py: its pure parts (placing a motion, facing, round trips), and the script
itself streaming DeepMimic's punch to a real `ringside spar-server` subprocess, its recorded
answer read back by an independent BVH reader (bvhio)."""

from __future__ import annotations

import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from bvh_readers import bvhio_positions
from conftest import query
from opponents import guard_opponents, spar_server

from models.humanoid.bvh import read_bvh
from models.humanoid.kinematics import BODY_NAMES, body_rotations, heading_yaw
from tasks.deepmimic import clip_path, load_deepmimic, retarget

REPO = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("spar_client", REPO / "examples" / "spar_client.py")
client = sys.modules["spar_client"] = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(client)


# ------------------------------------------------------------------ pure parts


@pytest.fixture(scope="module")
def punch(assets) -> np.ndarray:
    return retarget(load_deepmimic(clip_path(assets, "punch")))


def test_a_placed_motion_starts_where_and_facing_how_it_was_asked(punch):
    placed = client.place_motion(punch, offset=(1.5, -2.0), yaw=math.radians(150.0))
    assert placed[0, :2] == pytest.approx([1.5, -2.0], abs=1e-12)
    assert heading_yaw(placed[0, 3:7]) == pytest.approx(math.radians(150.0), abs=1e-9)
    # One rigid turn about z: heights, hinges, distances travelled and heading changes kept.
    assert placed[:, 2] == pytest.approx(punch[:, 2], abs=1e-12)
    assert placed[:, 7:] == pytest.approx(punch[:, 7:], abs=1e-12)
    travel = np.linalg.norm(np.diff(placed[:, :2], axis=0), axis=1)
    assert travel == pytest.approx(np.linalg.norm(np.diff(punch[:, :2], axis=0), axis=1))
    turn = client.wrap_angle(heading_yaw(placed[:, 3:7]) - heading_yaw(punch[:, 3:7]))
    assert turn == pytest.approx(turn[0], abs=1e-9)
    # The bodies' tilt relative to the vertical is untouched.
    vertical = body_rotations(placed)[..., 2, :] - body_rotations(punch)[..., 2, :]
    assert np.abs(vertical).max() < 1e-9


def test_placing_with_nothing_asked_leaves_the_motion_as_it_is(punch):
    same = client.place_motion(punch)
    sign = np.sign(np.sum(same[:, 3:7] * punch[:, 3:7], axis=1, keepdims=True))
    assert np.abs(np.c_[same[:, :3], same[:, 3:7] * sign, same[:, 7:]] - punch).max() < 1e-12


def test_facing_errors_are_the_heading_against_the_bearing_to_the_partner():
    opponent = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 1.0], [0.0, 0.0]])
    partner = np.array([[1.0, 0.0], [0.0, 2.0], [0.0, 1.0], [-1.0, 0.0]])
    heading = np.array([0.0, 0.0, math.pi, math.radians(-170.0)])
    errors = client.facing_errors(opponent, heading, partner)
    assert np.degrees(errors) == pytest.approx([0.0, -90.0, 0.0, 10.0], abs=1e-9)
    still = np.radians([0.0, 90.0, 180.0, 0.0])
    facts = client.facing_summary(np.array([0.0, 0.5, 1.0, 1.5]), errors, still)
    assert facts["within_30_deg"] == 0.75 and facts["still_mean_abs_deg"] == 67.5
    assert [w["mean_abs_deg"] for w in facts["per_window"]] == [45.0, 5.0]


def test_an_orbit_carries_the_motion_round_the_centre_and_turns_it_with_it(punch):
    placed = client.place_motion(punch, (1.2, 0.0), math.pi)
    carried = client.orbit_motion(placed, (0.0, 0.0), math.radians(30.0), 30.0)
    # After 2 s, 60 degrees round: the pelvis's distance to the centre and its heading relative
    # to the bearing from the centre are what they were.
    k = 60
    assert np.linalg.norm(placed[k, :2]) == pytest.approx(np.linalg.norm(carried[k, :2]))
    moved = math.atan2(carried[k, 1], carried[k, 0]) - math.atan2(placed[k, 1], placed[k, 0])
    assert client.wrap_angle(moved) == pytest.approx(math.pi / 3, abs=1e-9)
    turned = heading_yaw(carried[k, 3:7]) - heading_yaw(placed[k, 3:7])
    assert client.wrap_angle(turned) == pytest.approx(math.pi / 3, abs=1e-9)
    assert np.array_equal(carried[:, 7:], placed[:, 7:]) and carried[0] == pytest.approx(placed[0])


def test_an_approach_steps_the_motion_in_and_out_on_its_bearing(punch):
    """From 1.2 m, in to 0.6 m at 1 m/s (0.6 s), out to 3 m (2.4 s more) and in again; each
    frame on its own bearing from the centre, facing and pose as they were."""
    placed = client.place_motion(punch, (1.2, 0.0), math.pi)
    carried = client.orbit_motion(placed, (0.0, 0.0), math.radians(30.0), 30.0)
    stepped = client.approach_motion(carried, (0.0, 0.0), 0.6, 3.0, 1.0, 30.0)
    distance = np.linalg.norm(stepped[:, :2], axis=1)
    t = np.arange(len(stepped)) / 30.0
    expected = np.interp(t % 4.8, [0.0, 0.6, 3.0, 4.8], [1.2, 0.6, 3.0, 1.2])
    np.testing.assert_allclose(distance, expected, atol=1e-9)
    bearing = np.arctan2(stepped[:, 1], stepped[:, 0]) - np.arctan2(carried[:, 1], carried[:, 0])
    np.testing.assert_allclose(client.wrap_angle(bearing), 0.0, atol=1e-9)
    assert np.array_equal(stepped[:, 2:], carried[:, 2:])
    with pytest.raises(ValueError, match="near < far"):
        client.approach_motion(carried, (0.0, 0.0), 3.0, 0.6, 1.0, 30.0)


def test_round_trips_time_each_seq_to_the_first_state_that_acknowledged_it():
    sent = {0: 0.0, 1: 1.0, 2: 2.0, 3: 3.0}
    # seq 1 is overtaken by seq 2 before a state acknowledged it; seq 3 is never acknowledged.
    received = [(0.5, None), (0.6, 0), (1.2, 0), (2.3, 2), (2.9, 2)]
    assert client.round_trips(sent, received) == pytest.approx([0.6, 1.3, 0.3])
    assert client.percentiles_ms(np.array([0.01, 0.02, 0.03]))["p50"] == pytest.approx(20.0)
    assert client.percentiles_ms(np.array([]))["n"] == 0


# ------------------------------------------------------------------ against a real server


@pytest.fixture(scope="module")
def server(assets, tmp_path_factory):
    """`ringside spar-server` on opponent agent 1 of `guard_opponents`: (its URL, the folder)."""
    _, opponent = guard_opponents(assets, tmp_path_factory.mktemp("opponents"))
    with spar_server(opponent, tmp_path_factory.mktemp("served") / "data") as (url, _, _):
        yield url, opponent


@pytest.fixture(scope="module")
def sample_partner(sample_run: Path, tmp_path_factory) -> Path:
    """The sample's lifted partner (the adversary's opponent in the footage) as Ringside BVH."""
    from flows.cli import main

    out = tmp_path_factory.mktemp("motion")
    video = query(sample_run, "SELECT video_id FROM videos")[0][0]
    code = main(["--data", str(sample_run), "export-motion", "--video", video, "--out", str(out)])
    assert code == 0
    (partner,) = out.glob("opponent-*.bvh")
    return partner


def test_the_sample_partner_streamed_live_and_the_answer_read_back(
    server, sample_partner, tmp_path
):
    """Must-show 4 of the live-sparring issue: the sample's lifted partner streamed as the
    partner, carried round the opponent (`--orbit`), the opponent's answer read back by bvhio."""
    url, _ = server
    _, motion = read_bvh(sample_partner.read_text())
    answer, summary = tmp_path / "answer.bvh", tmp_path / "summary.json"
    loops = 2
    done = subprocess.run(
        [sys.executable, str(REPO / "examples" / "spar_client.py"), str(sample_partner)]
        + ["--url", url, "--loop", str(loops), "--orbit", "20"]
        + ["--answer", str(answer), "--summary", str(summary)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    frames = loops * len(motion)
    facts = json.loads(summary.read_text())
    names, positions = bvhio_positions(answer)
    assert names == list(BODY_NAMES)
    # A step finished past its 30 Hz slot may cost the bout a step (the server lets a missed slot
    # go rather than catch up): each late state may take a frame from the answer.
    slack = 2 + facts["late_states"]
    assert abs(len(positions) - frames) <= slack, (len(positions), frames, facts)
    # The opponent stands: its pelvis about a metre up, on the floor's side of the arena.
    assert 0.6 < np.median(positions[:, 0, 2]) < 1.2

    assert facts["errors"] == []
    assert facts["poses_sent"] == frames
    # The states received, likewise: a slot the server let go sent none (99 of 100 once here).
    assert facts["states_received"] >= frames - slack
    assert facts["answer_frames"] == len(positions)
    assert facts["answer_bones_from"] == "welcome"
    assert facts["round_trip_ms"]["n"] >= frames - 2
    assert 0 < facts["round_trip_ms"]["p50"] < 200
    assert facts["late_share"] == round(facts["late_states"] / facts["states_received"], 4)
    assert facts["facing"]["states"] == facts["states_received"]
    # Each fall of the opponent restarts it (a state marked `reset`); the partner, a puppet on
    # its footage, never touches the floor. Measured: no fall, no restart.
    assert facts["falls"]["partner"] == 0 and facts["falls"]["opponent"] <= facts["resets"]
    # By default the motion starts where the server put the partner, facing the opponent.
    assert np.hypot(*facts["placement"]["offset"]) > 0.3
    assert str(done.stdout).startswith(f"{facts['states_received']} states")
