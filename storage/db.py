"""The one DuckDB file: connections, migrations and transactions.

DuckDB allows one writing process at a time, so writers hold a connection only while they write and
wait for the file's lock when another process holds it.
"""

from __future__ import annotations

import functools
import re
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

import duckdb

LOCK_WAIT_S = 120.0

# DuckDB refuses a read-only and a writable connection to one file inside one process, and
# connections here are short, so a process takes turns with the database.
_PROCESS_LOCK = threading.RLock()


class DatabaseBusy(RuntimeError):
    """Another process held the database's lock for longer than we were willing to wait."""


class Interrupted(BaseException):
    """A signal arrived while DuckDB ran a query. DuckDB stops the query and raises
    ``RuntimeError("Query interrupted")`` in place of what the signal's handler raised (Prefect's
    TerminationSignal, a KeyboardInterrupt), so nothing above would know it was a stop; this
    says so again, and as a BaseException, which no ``except Exception`` swallows."""


# What DuckDB says of a file it cannot read: flipped bytes (a block's checksum), a truncated or
# emptied file.
_DAMAGE = ("corrupt database file", "not a valid duckdb database", "could not read enough bytes")


def damaged_database(error: BaseException) -> bool:
    """Whether ``error`` is DuckDB finding the database file damaged."""
    return isinstance(error, duckdb.Error) and any(d in str(error).lower() for d in _DAMAGE)


def error_line(error: BaseException) -> str:
    """An error in one line: its first line, a failed block checksum as where the damaged block
    is (DuckDB's own message runs on with two long checksums)."""
    text = str(error).strip()
    found = re.search(r"checksum .* in block at location (\d+)", text)
    if found:
        return f"a damaged block (bytes from {found.group(1)}: its checksum does not match)"
    return text.splitlines()[0] if text else type(error).__name__


def _is_lock_error(error: duckdb.Error) -> bool:
    return "lock" in str(error).lower()


def _open(path: Path, *, read_only: bool, wait_s: float) -> duckdb.DuckDBPyConnection:
    deadline = time.monotonic() + wait_s
    delay = 0.05
    while True:
        try:
            return duckdb.connect(str(path), read_only=read_only)
        except duckdb.IOException as error:
            if not _is_lock_error(error) or time.monotonic() > deadline:
                if _is_lock_error(error):
                    raise DatabaseBusy(
                        f"{path}: another process has held the database for over {wait_s:.0f} s"
                    ) from error
                raise
            time.sleep(delay)
            delay = min(delay * 2, 1.0)


# Stages that bring their own tables: stage name -> the folder of its migrations
# (`tasks.registry.register` adds them).
_STAGE_MIGRATIONS: dict[str, Traversable] = {}


def add_migrations(stage: str, folder: Traversable) -> None:
    """Apply ``folder``'s ``NNN_name.sql`` files, numbered per stage, to every database opened
    for writing from now on (a stage outside ``storage/migrations``)."""
    _STAGE_MIGRATIONS[stage] = folder


def remove_migrations(stage: str) -> None:
    _STAGE_MIGRATIONS.pop(stage, None)


def _read_migrations(folder: Traversable) -> list[tuple[int, str, str]]:
    found = []
    for entry in folder.iterdir():
        if entry.name.endswith(".sql"):
            number, _, rest = entry.name.partition("_")
            found.append((int(number), rest.removesuffix(".sql"), entry.read_text()))
    return sorted(found)


# Read once: every connection checks them, and the package's files do not change while it runs.
@functools.cache
def migrations() -> tuple[tuple[int, str, str], ...]:
    """The schema migrations shipped with the package, as (version, name, sql), in order."""
    return tuple(_read_migrations(resources.files("storage") / "migrations"))


def migrate(con: duckdb.DuckDBPyConnection) -> list[int]:
    """Apply the migrations this database has not seen yet, each in its own transaction: the
    package's, then each registered stage's own (`add_migrations`). Returns the package's
    versions applied."""
    con.execute(
        "CREATE TABLE IF NOT EXISTS schema_migrations "
        "(version INTEGER PRIMARY KEY, name VARCHAR NOT NULL, applied_at TIMESTAMP NOT NULL)"
    )
    applied = {row[0] for row in con.execute("SELECT version FROM schema_migrations").fetchall()}
    done = []
    for version, name, sql in migrations():
        if version not in applied:
            with transaction(con):
                con.execute(sql)
                con.execute(
                    "INSERT INTO schema_migrations VALUES (?, ?, ?)", [version, name, utcnow()]
                )
            done.append(version)
    for stage, folder in _STAGE_MIGRATIONS.items():
        applied = {
            row[0]
            for row in con.execute(
                "SELECT version FROM stage_migrations WHERE stage = ?", [stage]
            ).fetchall()
        }
        for version, name, sql in _read_migrations(folder):
            if version not in applied:
                with transaction(con):
                    con.execute(sql)
                    con.execute(
                        "INSERT INTO stage_migrations VALUES (?, ?, ?, ?)",
                        [stage, version, name, utcnow()],
                    )
    return done


def _migrated(con: duckdb.DuckDBPyConnection) -> bool:
    """Whether every migration this Ringside ships, and every registered stage's, is applied to
    ``con``'s database."""
    try:
        (newest,) = con.execute("SELECT max(version) FROM schema_migrations").fetchone()
        applied = set(con.execute("SELECT stage, version FROM stage_migrations").fetchall())
    except duckdb.CatalogException:
        return False
    wanted = {
        (stage, version)
        for stage, folder in _STAGE_MIGRATIONS.items()
        for version, _, _ in _read_migrations(folder)
    }
    return newest is not None and newest >= migrations()[-1][0] and wanted <= applied


@contextmanager
def connect(
    path: Path, *, read_only: bool = False, wait_s: float = LOCK_WAIT_S
) -> Iterator[duckdb.DuckDBPyConnection]:
    """A connection to the database at ``path``, migrated when writable, closed on exit.

    A read-only connection to a file that does not exist yet raises ``FileNotFoundError``. One
    to a file whose schema is behind this Ringside's (a process killed while it created the
    file, between DuckDB's first write and the migrations' commit; or a file of an older
    version) has it migrated first, through a writable connection, so that readers never meet
    a table that is not there yet.
    """
    if read_only and not path.exists():
        raise FileNotFoundError(f"{path}: no database yet (process a video first)")
    path.parent.mkdir(parents=True, exist_ok=True)
    with _PROCESS_LOCK:
        con = _open(path, read_only=read_only, wait_s=wait_s)
        if read_only and not _migrated(con):
            con.close()
            migrating = _open(path, read_only=False, wait_s=wait_s)
            try:
                migrate(migrating)
            finally:
                migrating.close()
            con = _open(path, read_only=True, wait_s=wait_s)
        try:
            if not read_only:
                migrate(con)
            yield con
        except RuntimeError as error:
            if str(error) == "Query interrupted":
                raise Interrupted(f"a query on {path} was stopped by a signal") from None
            raise
        finally:
            con.close()


@contextmanager
def transaction(con: duckdb.DuckDBPyConnection) -> Iterator[duckdb.DuckDBPyConnection]:
    """Everything inside commits together or not at all."""
    con.begin()
    try:
        yield con
    except BaseException:
        con.rollback()
        raise
    con.commit()


def utcnow() -> datetime:
    return datetime.now(UTC).replace(tzinfo=None)
