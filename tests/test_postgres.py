"""Prefect on PostgreSQL: `ringside serve` with Prefect's database in a real PostgreSQL cluster,
started here on a loopback port in a temporary directory (Debian's server: `make test` installs
it when run as root; elsewhere the test skips and says why)."""

from __future__ import annotations

import glob
import json
import os
import pwd
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from conftest import WAIT_S, api_post, flow_runs, wait_for

from flows.serve import free_port, run_progress, served_api

REPO = Path(__file__).resolve().parent.parent


def postgres_bin() -> Path | None:
    """The directory of PostgreSQL's server programs (initdb, pg_ctl), or None."""
    found = shutil.which("pg_ctl")
    if found:
        return Path(os.path.realpath(found)).parent
    versions = sorted(glob.glob("/usr/lib/postgresql/*/bin/pg_ctl"))
    return Path(versions[-1]).parent if versions else None


@pytest.fixture(scope="module")
def postgres():
    """A PostgreSQL cluster of its own, trust authentication on 127.0.0.1 only, with an empty
    database `prefect`; (connection URL for Prefect, a psql command line) while it runs."""
    bin_dir = postgres_bin()
    if bin_dir is None:
        pytest.skip(
            "no PostgreSQL server installed (Debian's postgresql package; `make test` installs "
            "it when run as root)"
        )
    # PostgreSQL refuses to run as root: as root, it runs as Debian's `postgres` user.
    as_user: list[str] = []
    root = Path(tempfile.mkdtemp(prefix="ringside-postgres-"))
    if os.geteuid() == 0:
        try:
            user = pwd.getpwnam("postgres")
        except KeyError:
            shutil.rmtree(root)
            pytest.skip("running as root and there is no `postgres` user to run PostgreSQL as")
        os.chown(root, user.pw_uid, user.pw_gid)
        as_user = ["runuser", "-u", "postgres", "--"]
    port = free_port()
    cluster = root / "cluster"

    def run(program: str, *args: str) -> str:
        done = subprocess.run(
            [*as_user, str(bin_dir / program), *args], capture_output=True, text=True
        )
        assert done.returncode == 0, f"{program}: {done.stderr[-2000:]}"
        return done.stdout

    run("initdb", "-D", str(cluster), "-U", "ringside", "-A", "trust", "--no-sync")
    options = f"-p {port} -k {root} -c listen_addresses=127.0.0.1 -c fsync=off"
    run("pg_ctl", "-D", str(cluster), "-l", str(root / "server.log"), "-o", options, "-w", "start")
    try:
        run("createdb", "-h", "127.0.0.1", "-p", str(port), "-U", "ringside", "prefect")
        psql = [
            *as_user,
            str(bin_dir / "psql"),
            *("-h", "127.0.0.1", "-p", str(port), "-U", "ringside", "-d", "prefect", "-At", "-c"),
        ]
        yield f"postgresql+asyncpg://ringside@127.0.0.1:{port}/prefect", psql
    finally:
        run("pg_ctl", "-D", str(cluster), "-m", "fast", "-w", "stop")
        shutil.rmtree(root)


def test_serve_on_postgresql_runs_scheduled_and_cli_runs(postgres, tmp_path, sample_video):
    database_url, psql = postgres
    data = tmp_path / "data"
    env = {k: v for k, v in os.environ.items() if k not in ("PREFECT_HOME", "PREFECT_API_URL")}
    env["PREFECT_API_DATABASE_CONNECTION_URL"] = database_url
    ringside = [sys.executable, "-m", "flows.cli", "--data", str(data)]
    log_path = tmp_path / "serve.log"
    with log_path.open("w") as log:
        serve = subprocess.Popen(
            [*ringside, "serve", "--port", str(free_port())],
            cwd=REPO,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    try:
        api = wait_for("`ringside serve` on PostgreSQL", lambda: served_api(data), log=log_path)

        def ringside_run(*argv: str) -> str:
            done = subprocess.run(
                [*ringside, *argv], cwd=REPO, env=env, capture_output=True, text=True,
                timeout=WAIT_S,
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
            lambda: (p := run_progress(data, scheduled)).finished and p,
            log=log_path,
        )
        assert progress.succeeded, progress.message
        second = sample_video.with_name("cam02.mp4")
        ringside_run("process", str(second), "--adversary", "A", "--until", "ingest", "--json")

        # Both read back through Prefect's API: the deployment's run and the CLI's.
        runs = {r["id"]: r for r in flow_runs(api, "video_to_opponent")}
        assert runs[scheduled]["state_type"] == "COMPLETED"
        assert runs[scheduled]["deployment_id"] is not None
        [cli_run] = [r for r in runs.values() if r["parameters"]["videos"] == [str(second)]]
        assert cli_run["state_type"] == "COMPLETED" and cli_run["deployment_id"] is None
        ingests = api_post(api, "flow_runs/filter", {"flows": {"name": {"any_": ["ingest"]}}})
        assert len(ingests) == 2 and {r["state_type"] for r in ingests} == {"COMPLETED"}
        # And they live in PostgreSQL: Prefect kept no SQLite database of its own.
        stored = subprocess.run(
            [*psql, "SELECT id FROM flow_run WHERE state_type = 'COMPLETED'"],
            capture_output=True, text=True, check=True,
        ).stdout.split()  # fmt: skip
        assert {scheduled, cli_run["id"]} <= set(stored)
        assert not list((data / "prefect").glob("*.db"))
    finally:
        serve.send_signal(signal.SIGTERM)
        code = serve.wait(timeout=60)
    assert code == 0, log_path.read_text(errors="replace")[-3000:]
