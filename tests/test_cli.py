"""The CLI and the Prefect pipeline end to end on real videos, DuckDB files and Prefect runs."""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import bvhio
import imageio_ffmpeg
import numpy as np
import pytest
from conftest import (
    TINY_PIPELINE_FLAGS,
    alive,
    child_pids,
    count,
    moving_box_frames,
    process_argv,
    run_cli,
    write_video,
)

import tasks.ingest.stage
from flows.cli import build_parser, main
from flows.serve import server_log_size
from models.humanoid.kinematics import BODY_NAMES, Y_UP_TO_Z_UP
from storage.db import connect
from storage.paths import data_paths


@pytest.fixture
def scans(monkeypatch) -> list[str]:
    """Every video the ingest stage actually decodes, in order: the stage's executed work."""
    seen: list[str] = []
    real = tasks.ingest.stage.scan_video

    def counting(path, config):
        seen.append(str(path))
        return real(path, config)

    monkeypatch.setattr(tasks.ingest.stage, "scan_video", counting)
    return seen


def test_second_run_does_no_work_and_rerun_recomputes(tmp_path, capsys, sample_video, scans):
    """The whole pipeline, video to opponent (tiny training and evaluation settings)."""
    data = str(tmp_path / "data")
    process = ["--data", data, "process", str(sample_video), "--adversary", "A"]
    process += TINY_PIPELINE_FLAGS
    code, out, _ = run_cli(capsys, *process, "--json")
    assert code == 0
    first = json.loads(out)
    stages = ["ingest", "pose", "lift", "dataset", "dataset-assemble", "train", "evaluate"]
    assert [(s["stage"], s["state"]) for s in first] == [(stage, "done") for stage in stages]
    assert len(scans) == 1

    code, out, _ = run_cli(capsys, *process, "--json")
    assert code == 0 and [s["state"] for s in json.loads(out)] == ["cached"] * 7
    assert len(scans) == 1, "a rerun with nothing changed decoded the video again"

    video_id = first[0]["video_id"]
    rerun = ["--data", data, "rerun", "ingest", "--video", video_id[:10], *TINY_PIPELINE_FLAGS]
    code, out, _ = run_cli(capsys, *rerun, "--json")
    # Ingest is recomputed; its key is unchanged, so the later stages are found in the cache.
    assert code == 0 and [s["state"] for s in json.loads(out)] == ["done"] + ["cached"] * 6
    assert len(scans) == 2
    db = Path(data) / "ringside.duckdb"
    runs = "SELECT stage, state, count(*) FROM stage_runs GROUP BY ALL ORDER BY ALL"
    with connect(db, read_only=True) as con:
        # Each computed output after ingest was noted as running first (an ingest takes
        # seconds, and its video is not listed before it is registered).
        assert con.execute(runs).fetchall() == [
            ("dataset", "cached", 2),
            ("dataset", "done", 1),
            ("dataset", "running", 1),
            ("evaluate", "cached", 2),
            ("evaluate", "done", 1),
            ("evaluate", "running", 1),
            ("ingest", "cached", 1),
            ("ingest", "done", 2),
            ("lift", "cached", 2),
            ("lift", "done", 1),
            ("lift", "running", 1),
            ("pose", "cached", 2),
            ("pose", "done", 1),
            ("pose", "running", 1),
            ("train", "cached", 2),
            ("train", "done", 1),
            ("train", "running", 1),
        ]
    assert count(db, "SELECT count(*) FROM ingest_probes") == 1

    code, out, _ = run_cli(capsys, "--data", data, "status", "--json")
    per_video = [
        {
            "video_id": video_id,
            "stage": s["stage"],
            "key": s["key"],
            "state": "cached",
            "error": None,
        }
        for s in first[:4]
    ]
    per_video[0]["state"] = "done"
    dataset_key, run_key = first[4]["key"], first[5]["key"]
    assert json.loads(out) == [
        *per_video,
        {
            "video_id": dataset_key,
            "stage": "train",
            "key": run_key,
            "state": "cached",
            "error": None,
        },
        {
            "video_id": run_key,
            "stage": "evaluate",
            "key": first[6]["key"],
            "state": "cached",
            "error": None,
        },
    ]

    # Without --json the run ends with the opponent: its folder (written), its bout, its numbers.
    code, out, _ = run_cli(capsys, *process)
    assert code == 0
    folder = Path(re.search(r"folder: (\S+)", out).group(1))
    assert (folder / "manifest.json").is_file() and (folder / "policy.onnx").is_file()
    assert Path(re.search(r"bout: +(\S+)", out).group(1)).is_file()
    falls = r"bouts ended by a fall, per simulated minute: [0-9.]+ \(untrained [0-9.]+"
    assert re.search(falls, out), out
    assert re.search(r"style score.*: [0-9.]+ \(untrained [0-9.]+, standing still [0-9.]+", out)
    # The sample's held-out split is too short for the two-sample test: it says so, and why.
    classifier = re.search(r"held-out classifier AUC.* told apart: (.+)", out).group(1)
    assert classifier.startswith("not measured (") and "validation" in classifier, classifier
    code, out, _ = run_cli(capsys, "spar", str(folder), "--seconds", "1", "--json")
    assert code == 0, out

    # Motion out for animation tools: the lifted fighters and the evaluated bouts as BVH, read
    # back by an independent reader (bvhio) with the humanoid's joints and every frame.
    export = ["--data", data, "export-motion", "--json"]
    code, out, _ = run_cli(capsys, *export, "--video", video_id[:8])
    assert code == 0, out
    lifted = json.loads(out)
    with connect(db, read_only=True) as con:
        lift_rows = con.execute(
            "SELECT role, count(*), min(step), max(step) + 1, arg_min(qpos, step) "
            "FROM lift_motion WHERE video_id = ? AND key = ? GROUP BY role",
            [video_id, first[2]["key"]],
        ).fetchall()
    # The sample is one shot and both fighters were lifted at every step: one file each.
    assert lifted["files"] == {
        f"{role}-shot0-steps{start}-{end}.bvh": steps for role, steps, start, end, _ in lift_rows
    }
    code, out, _ = run_cli(capsys, *export, "--run", run_key[:8])
    assert code == 0, out
    bouts = json.loads(out)
    assert sorted(bouts["files"]) == [
        f"bout{e:02d}-{role}.bvh" for e in range(4) for role in ("adversary", "opponent")
    ]
    for written in (lifted, bouts):
        for name, frames in written["files"].items():
            parsed = bvhio.readAsBvh(str(Path(written["folder"]) / name))
            assert parsed.FrameCount == frames
            assert [j.Name for j, _, _ in parsed.Root.layout()] == list(BODY_NAMES)
    for role, _, start, end, qpos in lift_rows:
        root = bvhio.readAsBvh(str(Path(lifted["folder"]) / f"{role}-shot0-steps{start}-{end}.bvh"))
        position = Y_UP_TO_Z_UP @ np.array(root.Root.Keyframes[0].Position) / 100
        assert np.allclose(position, qpos[:3], atol=1e-6)

    code, out, _ = run_cli(capsys, "--data", data, "metrics", "--stage", "ingest", "--json")
    metrics = {m["name"]: m["value"] for m in json.loads(out)}
    assert metrics["frames"] == 100 and metrics["fps"] == 60 and metrics["shot_cuts"] == 0
    assert set(json.loads(out)[0]) == {"video_id", "stage", "key", "name", "value"}


def test_changed_config_reruns_the_stage(tmp_path, capsys, two_shot_video, scans):
    data = str(tmp_path / "data")
    base = [
        "--data",
        data,
        "process",
        str(two_shot_video),
        "--adversary",
        "A",
        "--until",
        "ingest",
        "--json",
    ]
    code, out, _ = run_cli(capsys, *base)
    key = json.loads(out)[0]["key"]
    code, out, _ = run_cli(capsys, *base, "--ingest-chunk-frames", "7")
    assert code == 0 and json.loads(out)[0]["state"] == "done"
    assert json.loads(out)[0]["key"] != key
    assert len(scans) == 2
    db = Path(data) / "ringside.duckdb"
    assert (
        count(db, f"SELECT count(*) FROM ingest_chunks WHERE key = '{json.loads(out)[0]['key']}'")
        == 10
    )  # 2 shots of 30 frames, 5 chunks each
    # The other adversary declaration is another input, so another key.
    code, out, _ = run_cli(capsys, *base[:-1], "--adversary-colour", "red", "--json")
    assert json.loads(out)[0]["key"] != key and len(scans) == 3


def test_same_bytes_under_two_names_is_one_video(tmp_path, capsys, two_shot_video):
    data = str(tmp_path / "data")
    copy = tmp_path / "copy.mp4"
    shutil.copy(two_shot_video, copy)
    code, out, _ = run_cli(
        capsys,
        "--data",
        data,
        "process",
        str(two_shot_video),
        str(copy),
        "--adversary",
        "A",
        "--until",
        "ingest",
        "--json",
    )
    assert code == 0
    db = Path(data) / "ringside.duckdb"
    assert count(db, "SELECT count(*) FROM videos") == 1
    assert count(db, "SELECT count(*) FROM video_files") == 2


def _zeroed_frames(path: Path) -> Path:
    """A valid MP4 whose frame data is all zeros: it opens, but no frame decodes."""
    data = bytearray(path.read_bytes())
    at = 0
    while at < len(data):
        size = int.from_bytes(data[at : at + 4], "big")
        if data[at + 4 : at + 8] == b"mdat":
            data[at + 8 : at + size] = bytes(size - 8)
        at += size
    out = path.with_name("zeroed.mp4")
    out.write_bytes(bytes(data))
    return out


def _faststart_third(sample: Path, folder: Path) -> Path:
    """The sample with its index first, cut to a third: it opens, then stops decoding."""
    fast = folder / "fast.mp4"
    subprocess.run(
        [
            imageio_ffmpeg.get_ffmpeg_exe(),
            "-y",
            "-loglevel",
            "error",
            "-i",
            str(sample),
            "-c",
            "copy",
            "-movflags",
            "+faststart",
            str(fast),
        ],
        check=True,
    )
    cut = folder / "fast_third.mp4"
    cut.write_bytes(fast.read_bytes()[: fast.stat().st_size // 3])
    return cut


def bad_input(kind: str, folder: Path, sample: Path) -> tuple[Path, str]:
    if kind == "missing":
        return folder / "missing.mp4", "no such file"
    if kind == "directory":
        (folder / "clips.mp4").mkdir()
        return folder / "clips.mp4", "is a directory"
    if kind == "empty":
        (folder / "empty.mp4").touch()
        return folder / "empty.mp4", "is empty"
    if kind == "text":
        (folder / "notes.mp4").write_text("round 1: jab, jab, cross\n")
        return folder / "notes.mp4", "is not a video file"
    if kind == "third":
        (folder / "third.mp4").write_bytes(sample.read_bytes()[: sample.stat().st_size // 3])
        return folder / "third.mp4", "probably truncated or damaged"
    if kind == "faststart_third":
        return _faststart_third(sample, folder), "declares 100 frames but only"
    if kind == "no_frames":
        # Longer than dataset.min_clip_s, so that its header lets it reach ingest's decoding.
        written = write_video(folder / "written.mp4", moving_box_frames(40, (200, 60, 20)))
        return _zeroed_frames(written), "has no decodable video frames"
    if kind == "one_frame":
        # Refused from its header before any stage runs (ingest's own refusal: the next test).
        return write_video(folder / "one.mp4", moving_box_frames(1, (200, 60, 20))), (
            "(1 frame at 30 fps), shorter than the 1 s the dataset stage (dataset.min_clip_s) needs"
        )
    raise AssertionError(kind)


def db_snapshot(db: Path) -> tuple[str, dict[str, int]]:
    digest = hashlib.sha256(db.read_bytes()).hexdigest()
    with connect(db, read_only=True) as con:
        tables = [r[0] for r in con.execute("SELECT table_name FROM duckdb_tables()").fetchall()]
        counts = {t: con.execute(f"SELECT count(*) FROM {t}").fetchone()[0] for t in tables}
    return digest, counts


@pytest.fixture(scope="module")
def populated(tmp_path_factory, sample_video) -> Path:
    """A data directory that already holds one processed video."""
    data = tmp_path_factory.mktemp("populated") / "data"
    assert main(process_argv(data, sample_video, until="ingest")) == 0
    return data


@pytest.mark.parametrize(
    "kind",
    ["missing", "directory", "empty", "text", "third", "faststart_third", "no_frames", "one_frame"],
)
def test_bad_input_is_one_clear_line_and_changes_nothing(
    kind, tmp_path, capsys, populated, sample_video
):
    path, problem = bad_input(kind, tmp_path, sample_video)
    db = populated / "ringside.duckdb"
    before = db_snapshot(db)
    log = server_log_size(data_paths(populated))
    code, out, err = run_cli(
        capsys, "--data", str(populated), "process", str(path), "--adversary", "A"
    )
    assert code != 0
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert str(path) in lines[0] and problem in lines[0]
    assert db_snapshot(db) == before
    if kind in ("missing", "directory", "empty"):  # found without decoding: no server waited for
        assert server_log_size(data_paths(populated)) == log, "a Prefect server was started for it"


def test_a_video_of_too_few_frames_is_refused_by_ingest(tmp_path, capsys, populated):
    video = write_video(tmp_path / "one.mp4", moving_box_frames(1, (200, 60, 20)))
    db = populated / "ringside.duckdb"
    before = db_snapshot(db)
    code, _, err = run_cli(
        capsys, "--data", str(populated), "process", str(video), "--adversary", "A",
        "--until", "ingest",
    )  # fmt: skip
    lines = [line for line in err.splitlines() if line.strip()]
    assert code != 0 and len(lines) == 1, err
    assert "has 1 frame; at least 10 are needed (ingest.min_frames)" in lines[0]
    assert db_snapshot(db) == before


def test_two_processes_at_once_register_one_video(tmp_path, two_shot_video):
    # A data directory that does not exist yet, and Prefect's home left to its default in it.
    data = tmp_path / "new" / "data"
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_HOME"}
    env["RINGSIDE_DATA"] = str(data)
    command = [
        sys.executable,
        "-m",
        "flows.cli",
        "process",
        str(two_shot_video),
        "--adversary",
        "A",
        "--until",
        "ingest",
    ]
    procs = [
        subprocess.Popen(
            command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        for _ in range(2)
    ]
    for p in procs:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
    db = data / "ringside.duckdb"
    assert count(db, "SELECT count(*) FROM videos") == 1
    assert count(db, "SELECT count(*) FROM ingest_probes") == 1
    assert (data / "prefect").is_dir()
    assert count(db, "SELECT count(*) FROM stage_outputs") == 1


def test_rerun_of_an_unknown_video_is_clear(tmp_path, capsys, populated):
    code, _, err = run_cli(capsys, "--data", str(populated), "rerun", "ingest", "--video", "ffff")
    assert code == 2 and "--video ffff: matches no ingested video" in err


def test_status_and_metrics_on_an_empty_data_dir(tmp_path, capsys):
    assert run_cli(capsys, "--data", str(tmp_path), "status", "--json")[1].strip() == "[]"
    assert run_cli(capsys, "--data", str(tmp_path), "metrics", "--json")[1].strip() == "[]"


KILLED_MID_STAGE = """
import sys, time
import tasks.ingest.stage as stage
from flows.cli import build_parser, main

def stalled(path, config):
    print("mid-stage", flush=True)
    time.sleep(600)

stage.scan_video = stalled
main(sys.argv[1:])
"""


def test_killed_mid_stage_loses_nothing_and_rerun_finishes(
    tmp_path, capsys, sample_video, two_shot_video
):
    data = tmp_path / "data"
    assert main(process_argv(data, sample_video, until="ingest")) == 0
    capsys.readouterr()
    db = data / "ringside.duckdb"
    before = db_snapshot(db)
    env = {**os.environ, "PREFECT_HOME": str(tmp_path / "prefect")}
    victim = subprocess.Popen(
        [
            sys.executable,
            "-c",
            KILLED_MID_STAGE,
            "--data",
            str(data),
            "process",
            str(two_shot_video),
            "--adversary",
            "A",
            "--until",
            "ingest",
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        start_new_session=True,  # so its Prefect server can be killed with it
    )
    try:
        assert victim.stdout.readline().strip() == "mid-stage"
    finally:
        os.killpg(victim.pid, signal.SIGKILL)
        victim.wait()
    assert db_snapshot(db)[1] == before[1], "a killed run changed committed rows"

    code, out, _ = run_cli(
        capsys,
        "--data",
        str(data),
        "process",
        str(sample_video),
        str(two_shot_video),
        "--adversary",
        "A",
        "--until",
        "ingest",
        "--json",
    )
    assert code == 0
    assert [s["state"] for s in json.loads(out)] == ["cached", "done"]
    assert count(db, "SELECT count(*) FROM videos") == 2


KILLED_IN_POSE = """
import sys, time
import tasks.pose.task as pose

def stalled(*args, **kwargs):
    print("mid-pose", flush=True)
    time.sleep(600)

pose.process_chunk = stalled
from flows.cli import main
main(sys.argv[1:])
"""


def test_the_next_command_marks_a_killed_commands_flow_runs_crashed(tmp_path, capsys, sample_video):
    """A command killed in the pose stage leaves its flow runs RUNNING in Prefect (for ever, in
    `ringside serve`'s UI too); the next command on the data directory marks them Crashed, the
    stage's and the pipeline's above it."""
    from prefect.client.orchestration import get_client
    from prefect.client.schemas.objects import StateType
    from prefect.settings import PREFECT_API_URL, temporary_settings

    from flows.serve import private_server, stop_private_servers
    from storage.records import stale_runs

    data = tmp_path / "data"
    victim = subprocess.Popen(
        [sys.executable, "-c", KILLED_IN_POSE, *process_argv(data, sample_video, until="pose")],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        start_new_session=True,
    )
    try:
        assert victim.stdout.readline().strip() == "mid-pose"
    finally:
        os.killpg(victim.pid, signal.SIGKILL)
        victim.wait()
    with connect(data / "ringside.duckdb", read_only=True) as con:
        (stale,) = stale_runs(con)

    code, _, err = run_cli(capsys, *process_argv(data, sample_video, until="ingest"))
    assert code == 0, err
    api = private_server(data_paths(data))
    try:
        with (
            temporary_settings(updates={PREFECT_API_URL: api}),
            get_client(sync_client=True) as client,
        ):
            pose = client.read_flow_run(stale)
            pipeline = client.read_flow_run(
                client.read_task_run(pose.parent_task_run_id).flow_run_id
            )
    finally:
        stop_private_servers()
    assert pose.state.type == StateType.CRASHED, pose.state
    assert pipeline.state.type == StateType.CRASHED, pipeline.state
    assert "killed" in pose.state.message


def test_every_command_prints_its_help(capsys):
    """Settings' help texts hold '%' (argparse's format character): each command's --help works."""
    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for name in commands.choices:
        with pytest.raises(SystemExit) as stop:
            main([name, "--help"])
        assert stop.value.code == 0, name
        assert "usage: ringside" in capsys.readouterr().out


def test_help_and_a_mistyped_command_create_nothing(tmp_path):
    """`ringside --help` made ./data/prefect wherever it was typed."""
    env = {k: v for k, v in os.environ.items() if k not in ("PREFECT_HOME", "RINGSIDE_DATA")}
    for argv, code in ((["--help"], 0), (["process", "--help"], 0), (["proces"], 2)):
        done = subprocess.run(
            [sys.executable, "-m", "flows.cli", *argv],
            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert done.returncode == code, done.stderr
    assert not (tmp_path / "data").exists()
    assert list(tmp_path.iterdir()) == []


def test_an_error_in_a_flow_is_one_line_and_nothing_after_it(tmp_path):
    """An unknown dataset fails inside the train flow; the user reads one line (no `nanobind:
    leaked` reports at exit from the DuckDB objects the failed run's frames held)."""
    (tmp_path / "data").mkdir()
    with connect(tmp_path / "data" / "ringside.duckdb"):
        pass
    done = subprocess.run(
        [sys.executable, "-m", "flows.cli", "--data", str(tmp_path / "data"), "train", "--dataset",
         "nope"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2
    assert done.stderr.splitlines() == [done.stderr.splitlines()[0]], done.stderr
    assert "no dataset 'nope'" in done.stderr


def test_a_command_killed_with_sigkill_leaves_no_prefect_server(tmp_path, sample_video):
    """`kill -9` gives the command no chance to stop anything: the Prefect server it started
    goes with it (Prefect's own temporary server stayed, about 257 MB each)."""
    command = subprocess.Popen(
        [sys.executable, "-m", "flows.cli", "--data", str(tmp_path / "data"), "process",
         str(sample_video), "--adversary", "A"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    servers: list[int] = []
    deadline = time.monotonic() + 120
    while not servers and time.monotonic() < deadline and command.poll() is None:
        servers = child_pids(command.pid)
        time.sleep(0.2)
    time.sleep(5)  # the server is up and the command at work
    servers = child_pids(command.pid)
    assert servers and command.poll() is None, "the command started no server"
    command.kill()
    command.wait()
    deadline = time.monotonic() + 10
    while any(alive(pid) for pid in servers) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(alive(pid) for pid in servers)


@pytest.mark.parametrize(
    ("stop", "how"), [(signal.SIGTERM, "SIGTERM"), (signal.SIGINT, "Ctrl-C")], ids=["term", "int"]
)
def test_a_stop_signal_ends_a_command_in_one_line_within_5_s(tmp_path, sample_video, stop, how):
    # As a user runs it: Prefect's home in the data directory, where its runs are looked up.
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_HOME"}
    command = subprocess.Popen(
        [sys.executable, "-m", "flows.cli", "--data", str(tmp_path / "data"), "process",
         str(sample_video), "--adversary", "A"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    deadline = time.monotonic() + 120
    database = tmp_path / "data" / "ringside.duckdb"  # written once the pipeline's flow runs
    while not database.exists() and time.monotonic() < deadline:
        time.sleep(0.2)
    time.sleep(3)
    servers = child_pids(command.pid)
    assert servers and command.poll() is None
    command.send_signal(stop)
    stopped = time.monotonic()
    _, err = command.communicate(timeout=30)
    assert time.monotonic() - stopped < 5.0
    assert command.returncode != 0
    assert err.splitlines() == [
        f"ringside: error: stopped by {how}; the same command picks up where it stopped"
    ]
    assert [Path(f"/proc/{pid}/cmdline").read_bytes() for pid in servers if alive(pid)] == []
    # Its flow runs were marked as it stopped, not left Running for a later command to find.
    with sqlite3.connect(tmp_path / "data" / "prefect" / "prefect.db") as prefect_db:
        states = dict(prefect_db.execute("SELECT name, state_type FROM flow_run").fetchall())
    assert states and "RUNNING" not in states.values(), states
    assert "CRASHED" in states.values(), states
