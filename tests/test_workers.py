"""Workers: `ringside serve --workers 1` and a `ringside worker` beside it take four scheduled
runs from the work pool, two at a time, against a real Prefect server; the DuckDB file ends as a
serial run leaves it (slow: `make test-slow` runs it). A worker killed under `serve` is replaced,
its run stopped and marked Crashed, and the next run completes."""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import signal
import subprocess
import sys
import time
import urllib.error
from datetime import datetime
from pathlib import Path
from unittest import mock

import psutil
import pytest
from conftest import api_post, flow_runs, run_cli, stage_contents, wait_for

from flows.launch import run_progress, served_api
from flows.serve import WORK_POOL, free_port, worker_tmp_root
from storage.check import scan
from storage.paths import data_paths

REPO = Path(__file__).resolve().parent.parent


def online_workers(api: str) -> int:
    """Workers online on the pool (0 until `serve` has created it)."""
    try:
        found = api_post(api, f"work_pools/{WORK_POOL}/workers/filter", {})
    except urllib.error.HTTPError as error:
        if error.code == 404:
            return 0
        raise
    return sum(w["status"] == "ONLINE" for w in found)


def _overlap(a: dict, b: dict) -> float:
    """Seconds two finished flow runs ran at the same time."""
    start = max(datetime.fromisoformat(a["start_time"]), datetime.fromisoformat(b["start_time"]))
    end = min(datetime.fromisoformat(a["end_time"]), datetime.fromisoformat(b["end_time"]))
    return (end - start).total_seconds()


def scheduled_runs(
    capsys, paths, api: str, videos: list[Path], until: str, log: Path, env: dict | None = None
) -> list[dict]:
    """`ringside schedule VIDEO --until UNTIL` for each of ``videos`` on ``paths``' served
    server (with ``env`` set), waited for: each run succeeded; their flow runs, as the API has
    them."""
    scheduled = []
    # Scheduled together (in this process: a `schedule` command each took seconds to start).
    with mock.patch.dict(os.environ, env or {}):
        for video in videos:
            code, out, err = run_cli(
                capsys, "--data", str(paths.root), "schedule", str(video), "--adversary", "A",
                "--until", until, "--json",
            )  # fmt: skip
            assert code == 0, err
            scheduled.append(json.loads(out)["flow_run_id"])
    for run_id in scheduled:
        progress = wait_for(
            "the scheduled runs to finish",
            lambda run_id=run_id: (p := run_progress(paths, run_id)).finished and p,
            log=log,
        )
        assert progress.succeeded, progress.message
    return [r for r in flow_runs(api, "video_to_opponent") if r["id"] in scheduled]


def overlapped(runs: list[dict]) -> bool:
    """Whether some two of the finished flow ``runs`` ran at the same time."""
    return max(_overlap(a, b) for a, b in itertools.combinations(runs, 2)) > 0


# A minute long: with it CI's suite came near its 20 minutes, so `make test-slow` runs it.
@pytest.mark.slow
def test_two_workers_take_four_runs_two_at_a_time(tmp_path, capsys, sample_video):
    data = tmp_path / "data"
    paths = data_paths(data)
    videos = [sample_video.with_name(f"cam0{i}.mp4") for i in range(1, 5)]
    # As a user runs them: Prefect's home in the data directory.
    env = {k: v for k, v in os.environ.items() if k not in ("PREFECT_HOME", "PREFECT_API_URL")}
    ringside = [sys.executable, "-m", "flows.cli", "--data", str(data)]
    logs = {name: (tmp_path / f"{name}.log").open("w") for name in ("serve", "worker")}
    serve = subprocess.Popen(
        [*ringside, "serve", "--port", str(free_port()), "--workers", "1"],
        cwd=REPO, env=env, stdout=logs["serve"], stderr=subprocess.STDOUT,
    )  # fmt: skip
    worker = None
    try:
        api = wait_for("`ringside serve --workers 1`", lambda: served_api(paths))
        worker = subprocess.Popen(
            [*ringside, "worker"], cwd=REPO, env=env, stdout=logs["worker"],
            stderr=subprocess.STDOUT,
        )  # fmt: skip
        # Both workers take runs before any is scheduled (on a busy machine one came late).
        wait_for("two workers online on the pool", lambda: online_workers(api) >= 2)
        runs = scheduled_runs(capsys, paths, api, videos, "ingest", tmp_path / "serve.log")
        assert len(runs) == 4
        assert {r["work_pool_name"] for r in runs} == {WORK_POOL}
        # Two processes took them, two at a time: some pair of runs overlapped.
        assert overlapped(runs)
        below = psutil.Process(serve.pid).children(recursive=True)
        below += psutil.Process(worker.pid).children(recursive=True)
    finally:
        for process in (worker, serve):
            if process is not None:
                process.send_signal(signal.SIGTERM)
                assert process.wait(timeout=60) == 0
        for log in logs.values():
            log.close()
    # Stopped, the server and the workers with them.
    assert [p.pid for p in below if p.is_running() and p.status() != psutil.STATUS_ZOMBIE] == []
    assert "worker stopped" in (tmp_path / "worker.log").read_text()
    # The database holds what one process running the four videos in turn writes.
    assert scan(data_paths(data).db, data_paths(data).artifacts) == []
    serial = tmp_path / "serial"
    code, _, err = run_cli(
        capsys, "--data", str(serial), "process", *map(str, videos), "--adversary", "A",
        "--until", "ingest",
    )  # fmt: skip
    assert code == 0, err
    assert stage_contents(data) == stage_contents(serial)


def _worker_below(serve: subprocess.Popen) -> psutil.Process | None:
    """The Prefect worker process `serve` started (the newest one)."""
    found = []
    for process in psutil.Process(serve.pid).children():
        with contextlib.suppress(psutil.Error):  # a dead one, a zombie until `serve` reaps it
            if process.status() != psutil.STATUS_ZOMBIE and "worker" in process.cmdline():
                found.append(process)
    return max(found, key=lambda p: p.create_time()) if found else None


def _run_process(worker: psutil.Process, run_id: str) -> psutil.Process | None:
    for process in worker.children(recursive=True):
        with contextlib.suppress(psutil.Error):
            if process.environ().get("PREFECT__FLOW_RUN_ID") == run_id:
                return process
    return None


def test_a_killed_worker_is_replaced_its_run_crashed_and_the_next_run_completes(
    tmp_path, capsys, sample_video
):
    data = tmp_path / "data"
    paths = data_paths(data)
    env = {k: v for k, v in os.environ.items() if k not in ("PREFECT_HOME", "PREFECT_API_URL")}
    ringside = [sys.executable, "-m", "flows.cli", "--data", str(data)]
    log_path = tmp_path / "serve.log"
    log = log_path.open("w")
    serve = subprocess.Popen(
        [*ringside, "serve", "--port", str(free_port()), "--workers", "1"],
        cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT,
    )  # fmt: skip

    def schedule(until: str) -> str:
        with mock.patch.dict(os.environ):
            code, out, err = run_cli(
                capsys, "--data", str(data), "schedule", str(sample_video), "--adversary", "A",
                "--until", until, "--json",
            )  # fmt: skip
        assert code == 0, err
        return json.loads(out)["flow_run_id"]

    try:
        api = wait_for("`ringside serve --workers 1`", lambda: served_api(paths), log=log_path)
        wait_for("a worker online on the pool", lambda: online_workers(api) >= 1, log=log_path)
        worker = _worker_below(serve)
        first = schedule("lift")
        run = wait_for(
            "the run's process below the worker",
            lambda: _run_process(worker, first),
            log=log_path,
        )
        wait_for("the run to start", lambda: run_progress(paths, first).state == "Running")
        # Its temporary files go to the data directory, not the system's.
        assert str(worker_tmp_root(paths)) in run.environ()["TMPDIR"]
        worker.kill()
        killed = time.monotonic()
        replacement = wait_for(
            "a new worker",
            lambda: (w := _worker_below(serve)) is not None and w.pid != worker.pid and w,
            timeout_s=10,
            log=log_path,
        )
        assert time.monotonic() - killed < 10
        # The run the dead worker left is stopped and marked Crashed, not left to go on alone.
        progress = wait_for(
            "the killed worker's run to end",
            lambda: (p := run_progress(paths, first)).finished and p,
            timeout_s=30,
        )
        assert progress.state == "Crashed", progress
        # It reports itself Crashed as it takes SIGTERM, then ends (killed 10 s on, at most).
        wait_for(
            "the killed worker's run process to end",
            lambda: not run.is_running() or run.status() == psutil.STATUS_ZOMBIE,
            timeout_s=15,
        )
        wait_for("the new worker online", lambda: online_workers(api) >= 1, log=log_path)
        second = schedule("ingest")
        progress = wait_for(
            "the next run to finish",
            lambda: (p := run_progress(paths, second)).finished and p,
            log=log_path,
        )
        assert progress.succeeded, progress.message
        assert replacement.is_running()
    finally:
        serve.send_signal(signal.SIGTERM)
        assert serve.wait(timeout=60) == 0
        log.close()
    # The workers' temporary directories (Prefect's per-run ones in them) went with them.
    assert list(worker_tmp_root(paths).iterdir()) == []
    said = [line for line in log_path.read_text().splitlines() if f"worker {worker.pid}" in line]
    assert len(said) == 1 and f"worker {worker.pid} died (signal 9)" in said[0], said
    assert "its 1 flow run(s) stopped and marked Crashed" in said[0], said
