"""Several machines, one set of results: `ringside serve` on one data directory and two `ringside
worker`s on two others (separate working directories and temporary folders: nothing shared but
PostgreSQL, the lake's shared folder and the footage), three videos scheduled through `serve`.
Every output is computed once, `check` finds nothing, and the rows and metrics are those of one
local process running the same three videos in turn."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from unittest import mock

import pytest
from conftest import WAIT_S, render_page, run_cli, stage_contents, wait_for
from kill_rounds import GONE_WITHIN_S, descendants, survivors
from lakes import lake_env
from test_workers import online_workers, overlapped, scheduled_runs

from flows.launch import served_api
from flows.serve import free_port
from storage.check import scan
from storage.db import connect
from storage.paths import data_paths

REPO = Path(__file__).resolve().parent.parent
UNTIL = "pose"


def test_two_machines_compute_every_output_once_into_one_lake(tmp_path, capsys, sample_video, lake):
    videos = [sample_video.with_name(f"cam0{i}.mp4") for i in range(1, 4)]
    machines = {name: tmp_path / name for name in ("server", "first", "second")}
    base = {k: v for k, v in os.environ.items() if k not in ("PREFECT_HOME", "PREFECT_API_URL")}
    base.update(lake_env(lake))
    processes: dict[str, subprocess.Popen] = {}
    logs = {name: (tmp_path / f"{name}.log").open("w") for name in machines}

    def start(name: str, *argv: str, **env: str) -> None:
        # Each "machine" its own working directory and temporary folder.
        (tmp_path / f"{name}-tmp").mkdir()
        processes[name] = subprocess.Popen(
            [sys.executable, "-m", "flows.cli", "--data", str(machines[name]), *argv],
            cwd=machines[name].parent, env={**base, **env, "TMPDIR": str(tmp_path / f"{name}-tmp")},
            stdout=logs[name], stderr=subprocess.STDOUT,
        )  # fmt: skip

    server = data_paths(machines["server"])
    try:
        start("server", "serve", "--port", str(free_port()), "--workers", "1")
        api = wait_for("`ringside serve`", lambda: served_api(server), log=tmp_path / "server.log")
        for name in ("first", "second"):
            start(name, "worker", PREFECT_API_URL=api)
        wait_for("three workers online", lambda: online_workers(api) >= 3)
        runs = scheduled_runs(
            capsys, server, api, videos, UNTIL, tmp_path / "server.log", lake_env(lake)
        )
        assert overlapped(runs)
    finally:
        for name in ("second", "first", "server"):
            if name in processes:
                processes[name].send_signal(signal.SIGTERM)
                assert processes[name].wait(timeout=60) == 0, name
        for log in logs.values():
            log.close()
    # The runs took more than one machine: a run leaves its flow's persisted results in the
    # Prefect home of the machine that ran it.
    ran = [name for name, data in machines.items() if any((data / "prefect" / "storage").glob("*"))]
    assert len(ran) >= 2, ran
    # No machine wrote results of its own: no DuckDB file in any data directory.
    assert not [p for m in machines.values() for p in m.rglob("*.duckdb")]
    with connect(lake, read_only=True) as con:
        computed = con.execute(
            "SELECT stage, video_id, key, count(*) FROM stage_runs WHERE state = 'done' "
            "GROUP BY ALL ORDER BY ALL"
        ).fetchall()
    assert len(computed) == 3 * 2 and {n for *_, n in computed} == {1}, computed
    assert scan(lake, data_paths(machines["server"], str(lake), lake.shared).artifacts) == []
    # Any machine reads the same results: `status` from one, the dashboard from another.
    with mock.patch.dict(os.environ, {**lake_env(lake), "RINGSIDE_DATA": str(machines["second"])}):
        code, out, err = run_cli(capsys, "--data", str(machines["first"]), "status", "--json")
        assert code == 0, err
        states = {(r["stage"], r["video_id"]): r["state"] for r in json.loads(out)}
        assert sorted(states.values()).count("done") == 3 * 2, states
        from streamlit.testing.v1 import AppTest

        app = AppTest.from_function(render_page, args=("overview",), default_timeout=60).run()
        assert not app.exception and not app.error, (app.exception, app.error)
        shown = " ".join(str(table.value) for table in app.table)
        assert all(video_id[:12] in shown for _, video_id in states), shown[:500]
    serial = tmp_path / "serial"
    code, _, err = run_cli(
        capsys, "--data", str(serial), "process", *map(str, videos), "--adversary", "A",
        "--until", UNTIL,
    )  # fmt: skip
    assert code == 0, err
    assert stage_contents(lake) == stage_contents(serial)


# A minute long, and `tests/test_lake.py` kills writers mid-commit in `make test` already: the
# whole command killed on a lake runs in `make test-slow`.
@pytest.mark.slow
def test_a_run_killed_on_a_lake_leaves_nothing_partial_and_its_rerun_takes_its_claim(
    tmp_path, capsys, sample_video, lake
):
    # SIGKILL to the command alone while pose computes (its claim held in PostgreSQL), at a
    # random moment of it: what it started ends by itself, no partial output is visible, the
    # claim is free at once (the rerun does not wait), and the rerun completes.
    data = tmp_path / "data"
    env = {k: v for k, v in os.environ.items() if k not in ("PREFECT_HOME", "PREFECT_API_URL")}
    argv = ["--data", str(data), "process", str(sample_video), "--adversary", "A"]
    victim = subprocess.Popen(
        [sys.executable, "-m", "flows.cli", *argv, "--until", "pose"],
        cwd=REPO, env={**env, **lake_env(lake)}, stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    try:
        wait_for("pose to be computing", lambda: _computing(lake, "pose"))
        time.sleep(random.uniform(0.0, 4.0))
    finally:
        tree = descendants(victim.pid)
        victim.kill()
        victim.wait()
    wait_for("what the command started to end", lambda: not survivors(tree), GONE_WITHIN_S)
    with connect(lake, read_only=True) as con:
        poses = con.execute(
            "SELECT video_id, key FROM stage_outputs WHERE stage = 'pose'"
        ).fetchall()
        for video_id, key in poses:  # committed just before the kill: whole
            (rows,) = con.execute(
                "SELECT count(*) FROM pose_keypoints WHERE video_id = ? AND key = ?",
                [video_id, key],
            ).fetchone()
            assert rows > 0
    with mock.patch.dict(os.environ, lake_env(lake)):
        started = time.monotonic()
        code, out, err = run_cli(capsys, *argv, "--until", "pose", "--json")
        took = time.monotonic() - started
        assert code == 0, err
        assert "waiting for it" not in out + err
        assert {r["stage"]: r["state"] for r in json.loads(out)}["pose"] in (
            ("cached",) if poses else ("done",)
        )
    assert scan(lake, lake.shared / "artifacts") == []
    assert took < WAIT_S


def _computing(lake, stage: str) -> bool:
    if not lake.exists():
        return False
    with connect(lake, read_only=True) as con:
        (n,) = con.execute(
            "SELECT count(*) FROM stage_runs WHERE stage = ? AND state = 'running'", [stage]
        ).fetchone()
    return n > 0
