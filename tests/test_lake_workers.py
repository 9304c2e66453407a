"""Several machines, one set of results: `ringside serve` on one data directory and two `ringside
worker`s on two others (separate working directories and temporary folders: nothing shared but
PostgreSQL, the lake's shared folder and the footage), four videos scheduled through `serve`.
Every output is computed once, `check` finds nothing, and the rows and metrics are those of one
local process running the same four videos in turn."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from unittest import mock

from conftest import render_page, run_cli, stage_contents, wait_for
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
    videos = [sample_video.with_name(f"cam0{i}.mp4") for i in range(1, 5)]
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
    assert len(computed) == 4 * 2 and {n for *_, n in computed} == {1}, computed
    assert scan(lake, data_paths(machines["server"], str(lake), lake.shared).artifacts) == []
    # Any machine reads the same results: `status` from one, the dashboard from another.
    with mock.patch.dict(os.environ, {**lake_env(lake), "RINGSIDE_DATA": str(machines["second"])}):
        code, out, err = run_cli(capsys, "--data", str(machines["first"]), "status", "--json")
        assert code == 0, err
        states = {(r["stage"], r["video_id"]): r["state"] for r in json.loads(out)}
        assert sorted(states.values()).count("done") == 4 * 2, states
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
