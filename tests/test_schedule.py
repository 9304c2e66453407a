"""Scheduling: `ringside serve` (Prefect's server, the pipeline's deployment, a watched folder on
a schedule) and `ringside schedule`, against a real server and runner in a subprocess.

The watched folder's runs stop after ingest (`serve --until ingest`): the whole pipeline on the
sample takes minutes of pose and lift on 2 cores, and what is under test here is that the
schedule fires, finds the file and runs the pipeline on it, not the stages themselves.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path
from unittest import mock

import pytest
from conftest import WAIT_S, api_post, flow_runs, query, run_cli, wait_for

from flows.launch import (
    RunProgress,
    answers,
    pipeline_parameters,
    run_name,
    run_progress,
    served_api,
    served_file,
    submit_run,
)
from flows.serve import free_port, parse_when
from flows.watch import SeenFile, list_videos, sort_files
from storage.paths import data_paths

REPO = Path(__file__).resolve().parent.parent
EVERY_S = 10  # the watched folder's schedule in the test: an interval of seconds


def ringside(capsys, *argv: str) -> tuple[int, str, str]:
    """``ringside ARGV`` in this process; the environment is restored after, since ``main``
    points Prefect at the server of a served data directory through it."""
    with mock.patch.dict(os.environ):
        return run_cli(capsys, *argv)


def ingested(data: Path, path: Path) -> bool:
    """Whether ``path`` is registered and its ingest output committed."""
    if not (data / "ringside.duckdb").exists():
        return False
    rows = query(
        data,
        "SELECT count(*) FROM video_files f JOIN stage_outputs o USING (video_id) "
        "WHERE f.path = ? AND o.stage = 'ingest'",
        [str(path.resolve())],
    )
    return rows[0][0] > 0


@pytest.fixture(scope="module")
def served(tmp_path_factory, sample_video: Path):
    """`ringside serve` watching an empty folder every few seconds; stopped with SIGTERM."""
    root = tmp_path_factory.mktemp("serve")
    data, inbox = root / "data", root / "inbox"
    paths = data_paths(data)
    inbox.mkdir()
    port = free_port()
    env = dict(os.environ)
    # As a user runs it: Prefect's home in the data directory, not the tests' shared one.
    for name in ("PREFECT_HOME", "PREFECT_API_URL"):
        env.pop(name, None)
    log_path = root / "serve.log"
    log = log_path.open("w")
    command = [
        sys.executable,
        "-m",
        "flows.cli",
        "--data",
        str(data),
        "serve",
        "--watch",
        str(inbox),
        "--adversary",
        "Watched",
        "--every",
        str(EVERY_S),
        "--until",
        "ingest",
        "--port",
        str(port),
    ]
    process = subprocess.Popen(command, cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)
    try:
        api = wait_for("`ringside serve` to come up", lambda: served_api(paths), log=log_path)
        assert api == f"http://127.0.0.1:{port}/api"
        yield {"data": data, "inbox": inbox, "api": api, "port": port, "log": log_path}
    finally:
        process.send_signal(signal.SIGTERM)
        try:
            code = process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
            code = None
        log.close()
    # Stopped cleanly: its exit code, no server left behind, nothing saying it still serves.
    text = log_path.read_text(errors="replace")
    assert code == 0, text[-3000:]
    assert "serving stopped" in text
    assert not served_file(paths).exists()
    assert not answers(f"http://127.0.0.1:{port}/api", timeout_s=1)


def test_a_scheduled_run_processes_a_dropped_file(served, sample_video: Path):
    data, inbox, api = served["data"], served["inbox"], served["api"]
    assert f"Prefect UI: http://127.0.0.1:{served['port']}" in served["log"].read_text()
    # The schedule fires with nothing to do before any file arrives.
    wait_for(
        "a watch_folder run to complete",
        lambda: any(r["state_type"] == "COMPLETED" for r in flow_runs(api, "watch_folder")),
        log=served["log"],
    )
    dropped = inbox / "fight.mp4"
    # copy2 keeps the old modification time, so the file is settled at once; a file still being
    # written waits (tested on sort_files below).
    shutil.copy2(sample_video, dropped)
    wait_for(f"{dropped} to be ingested", lambda: ingested(data, dropped), log=served["log"])
    declared = query(
        data,
        "SELECT a.name FROM ingest_adversaries a JOIN video_files f USING (video_id) "
        "WHERE f.path = ?",
        [str(dropped.resolve())],
    )
    assert declared == [("Watched",)]

    def pipeline_done():
        runs = [
            r
            for r in flow_runs(api, "video_to_opponent")
            if r["parameters"].get("videos") == [str(dropped.resolve())]
        ]
        return runs if runs and runs[0]["state_type"] == "COMPLETED" else None

    # The pipeline ran inside a watch_folder run, and Prefect's API lists both.
    runs = wait_for("the watched file's pipeline run to complete", pipeline_done)
    assert len(runs) == 1 and runs[0]["parameters"]["until"] == "ingest"
    parents = api_post(
        api, "task_runs/filter", {"task_runs": {"id": {"any_": [runs[0]["parent_task_run_id"]]}}}
    )
    watcher_id = parents[0]["flow_run_id"]

    def watcher_done():
        [run] = api_post(api, "flow_runs/filter", {"flow_runs": {"id": {"any_": [watcher_id]}}})
        return run if run["state_type"] == "COMPLETED" else None

    watcher = wait_for("the watch_folder run that found it to complete", watcher_done)
    assert watcher["deployment_id"] is not None  # a run of the scheduled deployment
    # A later look leaves the registered file alone.
    done_at = datetime.now(UTC)
    wait_for(
        "a later watch_folder run",
        lambda: any(
            r["state_type"] == "COMPLETED" and datetime.fromisoformat(r["start_time"]) > done_at
            for r in flow_runs(api, "watch_folder")
        ),
    )
    again = [
        r
        for r in flow_runs(api, "video_to_opponent")
        if r["parameters"].get("videos") == [str(dropped.resolve())]
    ]
    assert len(again) == 1


def test_a_file_that_is_no_video_fails_once(served):
    """The watcher's run fails, naming the file, and later runs leave the file alone."""
    api, broken = served["api"], served["inbox"] / "broken.mp4"
    broken.write_bytes(b"not a video " * 100)
    os.utime(broken, (time.time() - 60, time.time() - 60))  # settled: written a minute ago

    def failed_runs():
        return [r for r in flow_runs(api, "watch_folder") if r["state_type"] == "FAILED"]

    [failed] = wait_for("a watch_folder run to fail on it", failed_runs, log=served["log"])
    assert str(broken.resolve()) in failed["state"]["message"]
    ledger = json.loads((served["data"] / "prefect" / "watch-ledger.json").read_text())
    assert str(broken.resolve()) in ledger
    failed_at = datetime.fromisoformat(failed["end_time"])
    wait_for(
        "a later watch_folder run to complete",
        lambda: any(
            r["state_type"] == "COMPLETED" and datetime.fromisoformat(r["start_time"]) > failed_at
            for r in flow_runs(api, "watch_folder")
        ),
    )
    assert len(failed_runs()) == 1


def test_schedule_runs_later_and_shows_in_prefect(served, capsys, sample_video: Path):
    data, api = served["data"], served["api"]
    video = sample_video.with_name("cam02.mp4")
    at = datetime.now().astimezone() + timedelta(seconds=8)
    code, out, err = ringside(
        capsys,
        "--data",
        str(data),
        "schedule",
        str(video),
        "--adversary",
        "Later",
        "--at",
        at.isoformat(timespec="seconds"),
        "--until",
        "ingest",
        "--json",
    )
    assert code == 0, err
    printed = json.loads(out)
    run_id = printed["flow_run_id"]
    assert printed["url"].endswith(f"/runs/flow-run/{run_id}")
    [run] = api_post(api, "flow_runs/filter", {"flow_runs": {"id": {"any_": [run_id]}}})
    assert run["state_type"] == "SCHEDULED"
    assert run["name"] == "cam02.mp4"
    expected = datetime.fromisoformat(run["expected_start_time"])
    assert abs(expected - at.replace(microsecond=0)) < timedelta(seconds=1)
    paths = data_paths(data)
    assert not run_progress(paths, run_id).finished
    progress = wait_for(
        "the scheduled run to finish",
        lambda: (p := run_progress(paths, run_id)).finished and p,
        log=served["log"],
    )
    assert progress == RunProgress("Completed", True, True, progress.message)
    [run] = api_post(api, "flow_runs/filter", {"flow_runs": {"id": {"any_": [run_id]}}})
    started = datetime.fromisoformat(run["start_time"])
    # Not before its time: the second `--at` asked for, not `at` with its microseconds (a run
    # once started at 21:39:59.77 for `--at 21:40:00`, taken at 21:39:52.90 + 8 s).
    asked = at.replace(microsecond=0).astimezone(UTC)
    assert started >= asked - timedelta(seconds=1)
    assert ingested(data, video)


def test_dashboard_rerun_goes_through_the_deployment(served, sample_video: Path):
    """What the dashboard's rerun button does: submit_run(pipeline_parameters(...))."""
    data = served["data"]
    video = served["inbox"] / "fight.mp4"
    wait_for(f"{video} to be ingested", lambda: ingested(data, video), log=served["log"])
    [(video_id,)] = query(
        data, "SELECT video_id FROM video_files WHERE path = ?", [str(video.resolve())]
    )
    paths = data_paths(data)
    parameters = pipeline_parameters(paths, video_id[:10], rerun=["ingest"])
    assert parameters["videos"] == [str(video.resolve())]
    assert parameters["adversary"] == "Watched" and parameters["rerun"] == ["ingest"]
    assert set(parameters["config"]) >= {"ingest", "pose", "lift", "dataset"}
    ingest_runs = (
        "SELECT state FROM stage_runs WHERE video_id = ? AND stage = 'ingest' ORDER BY created_at"
    )
    before = query(data, ingest_runs, [video_id])
    run_id = submit_run(paths, {**parameters, "until": "ingest"})  # the whole pipeline: minutes
    progress = wait_for(
        "the rerun to finish",
        lambda: (p := run_progress(paths, run_id)).finished and p,
        log=served["log"],
    )
    assert progress.succeeded, progress.message
    # Recomputed, not taken from the cache.
    after = query(data, ingest_runs, [video_id])
    assert after[-1] == ("done",) and after.count(("done",)) == before.count(("done",)) + 1


def test_cli_runs_report_to_the_served_server(served, sample_video: Path):
    data, api = served["data"], served["api"]
    video = sample_video.with_name("cam03.mp4")
    env = {k: v for k, v in os.environ.items() if k not in ("PREFECT_HOME", "PREFECT_API_URL")}
    command = ["-m", "flows.cli", "--data", str(data), "process", str(video), "--adversary", "Z"]
    ran = subprocess.run(
        [sys.executable, *command, "--until", "ingest", "--json"],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=WAIT_S,
    )
    assert ran.returncode == 0, ran.stderr[-3000:]
    runs = [
        r
        for r in flow_runs(api, "video_to_opponent")
        if r["parameters"].get("videos") == [str(video.resolve())]
    ]
    assert len(runs) == 1 and runs[0]["state_type"] == "COMPLETED"
    assert runs[0]["deployment_id"] is None  # started by the CLI, not through the deployment


def test_serve_refuses_a_second_serve_and_bad_options(served, capsys, tmp_path: Path):
    code, _, err = ringside(capsys, "--data", str(served["data"]), "serve")
    assert code == 2 and "served already" in err
    folder = tmp_path / "inbox"
    folder.mkdir()
    cases = {
        ("serve", "--watch", str(folder)): "--watch needs --adversary",
        ("serve", "--adversary", "X"): "--adversary goes with --watch",
        ("serve", "--watch", str(tmp_path / "nowhere"), "--adversary", "X"): "not a directory",
        ("serve", "--watch", str(folder), "--adversary", "X", "--every", "0"): "--every",
        ("serve", "--port", "0"): "--port",
        ("serve", "--port", str(served["port"])): "is in use",
        ("serve", "--watch", str(folder), "--adversary", "X", "--cron", "soon"): "cron",
    }
    for argv, expected in cases.items():
        code, _, err = ringside(capsys, "--data", str(tmp_path / "data"), *argv)
        assert code == 2 and expected in err and len(err.strip().splitlines()) == 1, (argv, err)


def test_schedule_errors_without_server_or_with_a_bad_time(capsys, tmp_path: Path, sample_video):
    data = str(tmp_path / "data")
    schedule = ("--data", data, "schedule", str(sample_video), "--adversary", "X")
    code, _, err = ringside(capsys, *schedule)
    assert code == 2 and "start `ringside serve` first" in err
    for at, expected in [("25:61", "no such time"), ("soonish", "ISO 8601")]:
        code, _, err = ringside(capsys, *schedule, "--at", at)
        assert code == 2 and f"--at {at}" in err and expected in err
    missing = tmp_path / "missing.mp4"
    code, _, err = ringside(capsys, "--data", data, "schedule", str(missing), "--adversary", "X")
    assert code == 2 and f"{missing}: no such file" in err
    paths = data_paths(data)
    with pytest.raises(ValueError, match="start `ringside serve` first"):
        submit_run(paths, {"videos": [str(sample_video)], "adversary": "X"})
    assert run_progress(paths, "00000000-0000-0000-0000-000000000000").state == "Unreachable"


def test_parse_when():
    now = datetime(2030, 6, 1, 18, 30, 15).astimezone()
    assert parse_when("now", now=now) == now
    assert parse_when("19:05", now=now) == now.replace(hour=19, minute=5, second=0)
    tomorrow = parse_when("07:00", now=now)
    assert tomorrow == (now + timedelta(days=1)).replace(hour=7, minute=0, second=0)
    assert parse_when("2030-06-02T10:00", now=now) == datetime(2030, 6, 2, 10).astimezone()
    assert parse_when("2030-06-02T10:00+00:00", now=now) == datetime(2030, 6, 2, 10, tzinfo=UTC)
    for bad, message in [
        ("2030-06-01T18:00", "in the past"),
        ("24:00", "no such time"),
        ("tomorrow", "ISO 8601"),
    ]:
        with pytest.raises(ValueError, match=message):
            parse_when(bad, now=now)


def test_sort_files_skips_registered_noted_and_unsettled():
    now_ns = 1_000 * 10**9
    old = now_ns - 60 * 10**9
    files = [
        SeenFile("/in/registered.mp4", 100, old),
        SeenFile("/in/replaced.mp4", 200, old),  # registered from this path, other bytes now
        SeenFile("/in/rejected.mp4", 300, old),
        SeenFile("/in/rejected-then-changed.mp4", 301, old),
        SeenFile("/in/copying.mp4", 400, now_ns - 2 * 10**9),
        SeenFile("/in/new.mp4", 500, old),
    ]
    seen = sort_files(
        files,
        registered_sizes={"/in/registered.mp4": 100, "/in/replaced.mp4": 150},
        ledger={
            "/in/rejected.mp4": {"size": 300, "mtime_ns": old, "why": "not a video"},
            "/in/rejected-then-changed.mp4": {"size": 300, "mtime_ns": old, "why": "x"},
        },
        now_ns=now_ns,
        settle_s=10.0,
    )
    assert [f.path for f in seen.candidates] == [
        "/in/replaced.mp4",
        "/in/rejected-then-changed.mp4",
        "/in/new.mp4",
    ]
    assert [f.path for f in seen.waiting] == ["/in/copying.mp4"]
    assert seen.known == 2


def test_list_videos_takes_video_files_only(tmp_path: Path):
    for name in ["b.MP4", "a.mov", ".partial.mp4", "notes.txt", "clip.mkv.part"]:
        (tmp_path / name).write_bytes(b"x")
    (tmp_path / "folder.mp4").mkdir()
    assert [Path(f.path).name for f in list_videos(tmp_path)] == ["a.mov", "b.MP4"]
    with pytest.raises(FileNotFoundError, match="watched folder"):
        list_videos(tmp_path / "gone")


def test_run_name():
    assert run_name({"videos": ["/a/x.mp4"]}) == "x.mp4"
    assert run_name({"videos": ["/a/x.mp4", "/b/y.mp4", "/c/z.mp4"], "rerun": ["pose"]}) == (
        "x.mp4 + y.mp4 + 1 more (rerun pose)"
    )
