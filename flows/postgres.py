"""A PostgreSQL cluster of Ringside's own for Prefect's server (`ringside postgres`): made once in
a folder of the data directory, started on 127.0.0.1 with trust authentication, as Debian's
`postgres` user when run as root (PostgreSQL refuses to run as root).

Trust on the loopback address opens nothing new: Prefect's API on 127.0.0.1 has no password
either, and the cluster holds only what that API serves.
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import subprocess
from collections.abc import Sequence
from pathlib import Path

from flows.serve import port_free
from storage.paths import LAKE_PREFIX
from storage.records import process_alive

# Not 5432, the port of a system PostgreSQL (Debian's own cluster) where there is one.
DEFAULT_PORT = 5433

# The cluster's superuser, the database Prefect's server keeps its runs in, and the one that
# holds Ringside's DuckLake catalog (`--results`).
USER = "ringside"
DATABASE = "prefect"
CATALOG = "ringside"

# UTF-8 with the C locale: valid whatever this machine's locale (a locale's own encoding must
# match the cluster's); Prefect needs no language's sort order.
ENCODING = ("-E", "UTF8", "--no-locale")

# Where Debian's postgresql package puts pg_ctl and the rest, one folder per version, off PATH.
DEBIAN_PROGRAMS = "/usr/lib/postgresql/*/bin/pg_ctl"


class PostgresError(Exception):
    """Why the cluster could not be started or stopped, in one line."""


def connection_url(port: int) -> str:
    """Prefect's `PREFECT_API_DATABASE_CONNECTION_URL` for the cluster on ``port``."""
    return f"postgresql+asyncpg://{USER}@127.0.0.1:{port}/{DATABASE}"


def results_setting(port: int) -> str:
    """The ``--results`` of the DuckLake catalog in the cluster on ``port``."""
    return f"{LAKE_PREFIX}dbname={CATALOG} host=127.0.0.1 port={port} user={USER}"


def running_port(folder: Path) -> int | None:
    """The port of the cluster in ``folder`` while its server runs, else None."""
    try:
        lines = (folder / "cluster" / "postmaster.pid").read_text().splitlines()
    except OSError:
        return None
    # Line 1 is the server's pid, line 4 its port; a server still starting may not have both.
    if len(lines) < 4 or not process_alive(int(lines[0])):
        return None
    return int(lines[3])


def start(folder: Path, port: int = DEFAULT_PORT) -> tuple[int, bool]:
    """Start the cluster in ``folder`` on 127.0.0.1:``port``, made the first time, with empty
    databases `prefect` and `ringside`; (the port it runs on, whether it was running already:
    then it is left on the port it has)."""
    if not 0 < port < 65536:
        raise ValueError(f"--port must be between 1 and 65535, got {port}")
    running = running_port(folder)
    if running is not None:
        return running, True
    programs = server_programs()
    run_as = _run_as()
    if not port_free(port):
        raise PostgresError(
            f"port {port} on 127.0.0.1 is in use (another PostgreSQL?); choose another with --port"
        )
    cluster = folder / "cluster"
    if not (cluster / "PG_VERSION").exists():
        _make_folder(folder, run_as)
        initdb = programs / "initdb"
        _run(initdb, "-D", cluster, "-U", USER, "-A", "trust", *ENCODING, run_as=run_as)
    # No Unix socket: its folder would need a short path the server's user may write to.
    options = f"-p {port} -c listen_addresses=127.0.0.1 -c unix_socket_directories=''"
    log = folder / "server.log"
    try:
        pg_ctl = programs / "pg_ctl"
        _run(pg_ctl, "-D", cluster, "-o", options, "-l", log, "-w", "start", run_as=run_as)
    except PostgresError as error:
        if "log output" not in str(error):
            raise
        # pg_ctl only says "Examine the log output."; the log's last line says why.
        last = log.read_text(errors="replace").strip().splitlines()[-1:]
        raise PostgresError(f"PostgreSQL did not start: {' '.join(last)} (log: {log})") from None
    _create_database(programs, port)
    return port, False


def stop(folder: Path) -> bool:
    """Stop the cluster in ``folder`` (open connections are closed); whether it was running."""
    if running_port(folder) is None:
        return False
    pg_ctl = server_programs() / "pg_ctl"
    _run(pg_ctl, "-D", folder / "cluster", "-m", "fast", "-w", "stop", run_as=_run_as())
    return True


def server_programs() -> Path:
    """The folder of PostgreSQL's programs (initdb, pg_ctl, psql): pg_ctl's on the PATH, else
    Debian's newest version."""
    found = shutil.which("pg_ctl")
    if found:
        return Path(os.path.realpath(found)).parent
    versions = glob.glob(DEBIAN_PROGRAMS)
    if not versions:
        raise PostgresError(
            "PostgreSQL's server (initdb, pg_ctl) is not installed: on Debian, "
            "`apt-get install postgresql`"
        )
    newest = max(versions, key=lambda p: [int(n) for n in Path(p).parts[-3].split(".")])
    return Path(newest).parent


def _run_as() -> list[str]:
    """The prefix that runs the server's programs as the `postgres` user when we are root."""
    if os.geteuid() != 0:
        return []
    try:
        pwd.getpwnam("postgres")
    except KeyError:
        raise PostgresError(
            "PostgreSQL refuses to run as root, and there is no `postgres` user to run it as "
            "(Debian's postgresql package makes one)"
        ) from None
    return ["runuser", "-u", "postgres", "--"]


def _make_folder(folder: Path, run_as: list[str]) -> None:
    """``folder``, owned by the user the server runs as, who must be able to reach it."""
    folder.mkdir(parents=True, exist_ok=True)
    if not run_as:
        return
    user = pwd.getpwnam("postgres")
    os.chown(folder, user.pw_uid, user.pw_gid)
    if subprocess.run([*run_as, "test", "-w", str(folder), "-a", "-x", str(folder)]).returncode:
        raise PostgresError(
            f"the `postgres` user cannot reach {folder}: a folder above it is closed to other "
            "users (open it with chmod o+x, or give --data a folder it can reach)"
        )


def _create_database(programs: Path, port: int) -> None:
    """The databases `prefect` and `ringside` (the catalog), unless a start before made them."""
    where = ["-h", "127.0.0.1", "-p", str(port), "-U", USER]
    for name in (DATABASE, CATALOG):
        query = f"SELECT 1 FROM pg_database WHERE datname = '{name}'"
        if not _run(programs / "psql", "-X", *where, "-d", "postgres", "-Atc", query).strip():
            _run(programs / "createdb", *where, name)


def _run(program: Path, *args: str | Path, run_as: Sequence[str] = ()) -> str:
    """Run one of PostgreSQL's programs; its output, or a PostgresError with its last line."""
    argv = [*run_as, str(program), *map(str, args)]
    # From /, which the `postgres` user may read when we run it as that user.
    done = subprocess.run(argv, capture_output=True, text=True, cwd="/")
    if done.returncode != 0:
        why = (done.stderr.strip().splitlines() or [f"exit status {done.returncode}"])[-1]
        raise PostgresError(f"{program.name}: {why}")
    return done.stdout
