"""Prefect on PostgreSQL: docs/prefect.md's commands run as written (`ringside postgres`, `ringside
serve` with the URL it printed, `ringside postgres --stop`), in a temporary data directory on
free ports, with a scheduled run and a CLI run. Debian's server: `make test` installs it when run
as root; elsewhere the tests skip and say why."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pytest
from conftest import WAIT_S, api_post, flow_runs, wait_for
from lakes import skip_without_postgresql

import flows.postgres
from flows.cli import main
from flows.launch import run_progress, served_api
from flows.postgres import running_port, server_programs
from flows.serve import free_port
from storage.db import connect, is_lake
from storage.paths import data_paths

REPO = Path(__file__).resolve().parent.parent


def readme_commands(port: int) -> list[str]:
    """The lines of docs/prefect.md's shell block under "Prefect on PostgreSQL", comments dropped,
    with ``port`` for PostgreSQL's 5433."""
    readme = (REPO / "docs" / "prefect.md").read_text()
    block = re.search(r"## Prefect on PostgreSQL\n.*?```sh\n(.*?)```", readme, re.S).group(1)
    lines = [re.sub(r"\s+#.*", "", line) for line in block.splitlines()]
    return [line.replace("5433", str(port)) for line in lines if line]


@dataclass(frozen=True)
class Served:
    data: Path
    env: dict[str, str]
    start_line: str
    printed: str  # what docs/prefect.md's `ringside postgres` printed on stdout
    serve_line: str
    psql: list[str]  # psql on the database `prefect`, to be given -c SQL
    api: str
    log: Path


def shell(line: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        ["bash", "-c", line], env=env, capture_output=True, text=True, timeout=WAIT_S
    )


@pytest.fixture(scope="module")
def served():
    """docs/prefect.md's block run as written, on the data directory `$RINGSIDE_DATA` of a temporary
    folder: PostgreSQL started on a free port, then `ringside serve` on it (on a free port too,
    its only addition); both stopped at the end, `serve` first, as docs/prefect.md says."""
    skip_without_postgresql()
    root = Path(tempfile.mkdtemp(prefix="ringside-postgres-"))
    # As root the cluster runs as the `postgres` user, who must reach DATA/postgres.
    root.chmod(0o755)
    data = root / "data"
    paths = data_paths(data)
    port = free_port()
    start_line, serve_line, stop_line = readme_commands(port)
    env = {k: v for k, v in os.environ.items() if k not in ("PREFECT_HOME", "PREFECT_API_URL")}
    env["RINGSIDE_DATA"] = str(data)
    # `ringside` as installed beside this Python.
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env['PATH']}"
    serve, log = None, root / "serve.log"
    try:
        started = shell(start_line, env)
        assert started.returncode == 0, started.stderr
        with log.open("w") as out:
            serve = subprocess.Popen(
                # `exec env`: the SIGTERM that ends it reaches `ringside serve` itself.
                ["bash", "-c", f"exec env {serve_line} --port {free_port()}"],
                env=env, stdout=out, stderr=subprocess.STDOUT,
            )  # fmt: skip
        wait_for(
            "`ringside serve` on PostgreSQL", lambda: served_api(paths) or serve.poll() is not None
        )
        api = served_api(paths)
        assert api, log.read_text(errors="replace")[-3000:]
        where = ("-h", "127.0.0.1", "-p", str(port), "-U", "ringside", "-d", "prefect")
        psql = [str(server_programs() / "psql"), "-X", *where, "-At", "-c"]
        yield Served(data, env, start_line, started.stdout, serve_line, psql, api, log)
    finally:
        serve_code = None
        if serve is not None:
            serve.send_signal(signal.SIGTERM)
            try:
                serve_code = serve.wait(timeout=60)
            except subprocess.TimeoutExpired:
                serve.kill()
                serve_code = serve.wait()
            serve_tail = log.read_text(errors="replace")[-3000:]
        stopped = shell(stop_line, env)
        # No server of ours may outlive the tests, whatever docs/prefect.md's line did.
        flows.postgres.stop(data / "postgres")
        shutil.rmtree(root)
    assert serve_code in (None, 0), serve_tail
    assert stopped.returncode == 0 and "stopped" in stopped.stdout, stopped.stderr


def test_the_readme_commands_keep_prefects_tables_in_postgresql(served):
    # What `ringside postgres` printed is the setting docs/prefect.md's serve line gives.
    assert served.printed.splitlines() == [served.serve_line.removesuffix(" ringside serve")]
    tables = subprocess.run(
        [*served.psql, "SELECT tablename FROM pg_tables WHERE schemaname = 'public'"],
        capture_output=True, text=True, check=True,
    ).stdout.split()  # fmt: skip
    assert {"flow_run", "task_run", "deployment", "alembic_version"} <= set(tables)
    assert running_port(served.data / "postgres") is not None
    # Run again while it runs: it says so, prints the same line, exit 0.
    again = shell(served.start_line, served.env)
    assert again.returncode == 0, again.stderr
    assert "already running" in again.stderr
    assert again.stdout == served.printed


def test_the_cluster_holds_a_ducklake_catalog_for_the_results(served, tmp_path):
    # docs/scaling.md's first step: `ringside postgres --lake` prints the setting of the
    # catalog database `ringside` made beside Prefect's, and a lake opens on it.
    port = running_port(served.data / "postgres")
    printed = shell(served.start_line.replace("postgres", "postgres --lake", 1), served.env)
    assert printed.returncode == 0, printed.stderr
    name, _, setting = printed.stdout.strip().partition("=")
    assert name == "RINGSIDE_RESULTS"
    assert setting == f"ducklake:postgres:dbname=ringside host=127.0.0.1 port={port} user=ringside"
    lake = data_paths(tmp_path / "data", setting, tmp_path / "shared").lake
    with connect(lake) as con:
        assert is_lake(con)
        assert con.execute("SELECT count(*) FROM schema_migrations").fetchone()[0] > 0


def test_serve_on_postgresql_runs_scheduled_and_cli_runs(served, sample_video):
    data = served.data

    def ringside_run(*argv: str) -> str:
        done = subprocess.run(
            [sys.executable, "-m", "flows.cli", *argv], cwd=REPO, env=served.env,
            capture_output=True, text=True, timeout=WAIT_S,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr[-3000:]
        return done.stdout

    scheduled = json.loads(
        ringside_run(
            "schedule",
            str(sample_video),
            "--adversary",
            "A",
            "--at",
            "now",
            "--until",
            "ingest",
            "--json",
        )  # fmt: skip
    )["flow_run_id"]
    progress = wait_for(
        "the scheduled run to finish",
        lambda: (p := run_progress(data_paths(data), scheduled)).finished and p,
        log=served.log,
    )
    assert progress.succeeded, progress.message
    second = sample_video.with_name("cam02.mp4")
    ringside_run("process", str(second), "--adversary", "A", "--until", "ingest", "--json")

    # Both read back through Prefect's API: the deployment's run and the CLI's.
    runs = {r["id"]: r for r in flow_runs(served.api, "video_to_opponent")}
    assert runs[scheduled]["state_type"] == "COMPLETED"
    assert runs[scheduled]["deployment_id"] is not None
    [cli_run] = [r for r in runs.values() if r["parameters"]["videos"] == [str(second)]]
    assert cli_run["state_type"] == "COMPLETED" and cli_run["deployment_id"] is None
    ingests = api_post(served.api, "flow_runs/filter", {"flows": {"name": {"any_": ["ingest"]}}})
    assert len(ingests) == 2 and {r["state_type"] for r in ingests} == {"COMPLETED"}
    # And they live in PostgreSQL: Prefect kept no SQLite database of its own.
    stored = subprocess.run(
        [*served.psql, "SELECT id FROM flow_run WHERE state_type = 'COMPLETED'"],
        capture_output=True, text=True, check=True,
    ).stdout.split()  # fmt: skip
    assert {scheduled, cli_run["id"]} <= set(stored)
    assert not list((data / "prefect").glob("*.db"))


def test_a_port_in_use_is_one_line_and_makes_no_cluster(tmp_path):
    skip_without_postgresql()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = subprocess.run(
            [sys.executable, "-m", "flows.cli", "--data", str(tmp_path), "postgres", "--port",
             str(port)],
            cwd=REPO, capture_output=True, text=True, timeout=WAIT_S,
        )  # fmt: skip
    assert done.returncode == 1
    assert done.stderr.splitlines() == [
        f"ringside: error: port {port} on 127.0.0.1 is in use (another PostgreSQL?); "
        "choose another with --port"
    ]
    assert not (tmp_path / "postgres").exists()


def test_without_postgresql_the_error_names_debians_package(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setattr(flows.postgres, "DEBIAN_PROGRAMS", str(tmp_path / "*/bin/pg_ctl"))
    assert main(["--data", str(tmp_path / "data"), "postgres"]) == 1
    [line] = capsys.readouterr().err.splitlines()
    assert line.startswith("ringside: error: PostgreSQL's server (initdb, pg_ctl) is not installed")
    assert "apt-get install postgresql" in line
    assert main(["--data", str(tmp_path / "data"), "postgres", "--stop"]) == 0
