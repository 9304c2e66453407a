"""A PostgreSQL cluster for the tests of the results' lake backend, and a fresh lake (catalog
database and shared folder) per test: `storage.paths.Lake` as `ringside postgres` makes one.
Debian's server: `make test` installs it when run as root; elsewhere the tests skip."""

from __future__ import annotations

import itertools
import os
import pwd
import subprocess
from pathlib import Path

import pytest

import flows.postgres
from flows.postgres import USER, PostgresError, server_programs
from flows.serve import free_port
from storage.paths import Lake

_made = itertools.count()


def skip_without_postgresql() -> None:
    try:
        server_programs()
    except PostgresError as error:
        pytest.skip(f"{error} (`make test` installs it when run as root)")
    if os.geteuid() == 0:
        try:
            pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root and there is no `postgres` user to run PostgreSQL as")


def start_cluster(folder: Path) -> int:
    """A cluster of `flows.postgres` in ``folder`` on a free port; its port."""
    skip_without_postgresql()
    folder.mkdir(parents=True, exist_ok=True)
    folder.chmod(0o755)  # as root the server runs as `postgres`, who must reach it
    port, _ = flows.postgres.start(folder / "postgres", free_port())
    return port


def stop_cluster(folder: Path) -> None:
    flows.postgres.stop(folder / "postgres")


def new_lake(port: int, shared: Path) -> Lake:
    """A lake of its own: an empty catalog database in the cluster on ``port``, ``shared`` its
    folder."""
    name = f"lake_{os.getpid()}_{next(_made)}"
    where = ["-h", "127.0.0.1", "-p", str(port), "-U", USER]
    subprocess.run([str(server_programs() / "createdb"), *where, name], check=True)
    return Lake(f"dbname={name} host=127.0.0.1 port={port} user={USER}", shared)


def lake_env(lake: Lake) -> dict[str, str]:
    """The environment that points a `ringside` command at ``lake``."""
    return {"RINGSIDE_RESULTS": str(lake), "RINGSIDE_SHARED": str(lake.shared)}
