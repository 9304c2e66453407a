"""The results database: connections, migrations and transactions.

Two backends behind one `connect`: the data directory's DuckDB file (the default), and a DuckLake
catalog on PostgreSQL (`storage.paths.Lake`) that processes on many machines write at once.

DuckDB allows one writing process at a time on a file, so writers hold a connection only while
they write and wait for the file's lock when another process holds it. A lake has no such lock:
each transaction commits a snapshot in PostgreSQL, and one that conflicts with a snapshot
committed meanwhile is run again (`transact`).
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import random
import re
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import TypeVar

import duckdb

from storage.paths import Lake

T = TypeVar("T")

LOCK_WAIT_S = 120.0

# DuckDB refuses a read-only and a writable connection to one file inside one process, and
# connections here are short, so a process takes turns with the database.
_PROCESS_LOCK = threading.RLock()


class DatabaseBusy(RuntimeError):
    """Another process held the database's lock for longer than we were willing to wait."""


class DatabaseTooNew(ValueError):
    """The file was written by a DuckDB whose storage version this one cannot read (Ringside
    pinned 2.0.0 before it pinned 1.4.4 for DuckLake)."""


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
    # Not just "lock": a damaged block's message ("... in block at location ...") has it too.
    return "could not set lock" in str(error).lower()


def _open(path: Path, *, read_only: bool, wait_s: float) -> duckdb.DuckDBPyConnection:
    deadline = time.monotonic() + wait_s
    delay = 0.05
    while True:
        try:
            return duckdb.connect(str(path), read_only=read_only)
        except duckdb.IOException as error:
            found = re.search(r"version number (\d+), but we can only read versions", str(error))
            if found:
                raise DatabaseTooNew(
                    f"{path} was written by a newer DuckDB (storage version {found.group(1)}) "
                    f"than this Ringside's {duckdb.__version__}: export it with the DuckDB that "
                    "wrote it (EXPORT DATABASE) and import it with this one (IMPORT DATABASE)"
                ) from None
            if not _is_lock_error(error) or time.monotonic() > deadline:
                if _is_lock_error(error):
                    raise DatabaseBusy(
                        f"{path}: another process has held the database for over {wait_s:.0f} s"
                    ) from error
                raise
            time.sleep(delay)
            delay = min(delay * 2, 1.0)


# The name a lake is attached under; `USE` makes it what unqualified table names mean.
LAKE_ALIAS = "results"


def _extension_directory() -> str:
    """Where the `duckdb-ext-ducklake` and `duckdb-ext-postgres` wheels put the extensions'
    binaries: loaded from there, never downloaded at run time."""
    spec = importlib.util.find_spec("duckdb_ext")
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError(
            "the DuckLake backend needs the packages duckdb-ext-ducklake and duckdb-ext-postgres"
        )
    return str(Path(next(iter(spec.submodule_search_locations))) / "extensions")


def _unreachable(error: duckdb.Error) -> bool:
    """Whether ``error`` is PostgreSQL not answering (down, restarting), not a refusal."""
    text = str(error).lower()
    return any(
        s in text
        for s in ("connection refused", "could not connect", "server closed the connection",
                  "the database system is", "terminating connection", "no connection to")
    )  # fmt: skip


def _initialised_meanwhile(error: duckdb.Error) -> bool:
    """Whether ``error`` is DuckLake's first attach of an empty catalog finding the catalog's
    tables made meanwhile by another process's first attach (a team's workers starting at
    once): PostgreSQL refuses the second CREATE TABLE, and attaching again reads the catalog
    the other made."""
    text = str(error)
    return "Failed to initialize DuckLake" in text and (
        "already exists" in text or "pg_type_typname_nsp_index" in text
    )


class CatalogUnreachable(RuntimeError):
    """The lake's PostgreSQL did not answer within the wait."""


def _open_lake(lake: Lake, *, read_only: bool, wait_s: float) -> duckdb.DuckDBPyConnection:
    """An in-memory DuckDB with the lake attached and in use. PostgreSQL not answering (a
    restart) is waited for up to ``wait_s``, then raised in one line; a first attach that
    another process's first attach beat to the catalog's tables is tried again."""
    deadline = time.monotonic() + wait_s
    delay = 0.1
    while True:
        con = duckdb.connect(
            config={
                "extension_directory": _extension_directory(),
                "autoinstall_known_extensions": False,
                "autoload_known_extensions": False,
                # Checking the two binaries' signatures took 450-770 ms of every connection
                # (benchmarks/lake_commits.py); they are the files pip installed from the
                # registry's wheels, and only they are loaded, by name, from that folder.
                "allow_unsigned_extensions": True,
            }
        )
        try:
            # DuckDB draws a progress bar on stdout for a query past 2 s, piped or not: in the
            # middle of a command's JSON, or of what a parent reads off a child's stdout (a
            # catalog's queries over the network get there on a loaded machine).
            con.execute("SET enable_progress_bar = false")
            con.execute("LOAD ducklake")
            con.execute("LOAD postgres")
            options = f"DATA_PATH '{lake.data_path}/'" + (", READ_ONLY" if read_only else "")
            con.execute(f"ATTACH '{lake}' AS {LAKE_ALIAS} ({options})")
            con.execute(f"USE {LAKE_ALIAS}")
            if not read_only:
                # Made once the attach has made the catalog, not before: the folder is how a
                # reader knows the lake exists (`Lake.exists`), and one that attached between
                # the two found no catalog.
                lake.data_path.mkdir(parents=True, exist_ok=True)
            return con
        except duckdb.Error as error:
            con.close()
            if _initialised_meanwhile(error) and time.monotonic() <= deadline:
                time.sleep(random.uniform(0, delay))
                continue
            if not _unreachable(error):
                raise
            if time.monotonic() > deadline:
                raise CatalogUnreachable(
                    f"{lake}: PostgreSQL did not answer for {wait_s:.0f} s ({error_line(error)})"
                ) from error
            time.sleep(delay)
            delay = min(delay * 2, 2.0)


def is_lake(con: duckdb.DuckDBPyConnection) -> bool:
    """Whether ``con``'s current database is a DuckLake catalog."""
    (kind,) = con.execute(
        "SELECT type FROM duckdb_databases() WHERE database_name = current_database()"
    ).fetchone()
    return kind == "ducklake"


# What a DuckLake table cannot have, taken out of the migrations' DDL for a lake, once, here:
# - constraints other than NOT NULL (primary keys, CHECKs): the stores never rely on them to
#   refuse a row (a stage's rows are replaced by a DELETE and an INSERT in one transaction, and
#   the claims keep to one computation per output), so the lake goes without; a column declared
#   `PRIMARY KEY` keeps the NOT NULL that implies (as the file's does);
# - fixed-size arrays (FLOAT[33]) become lists (FLOAT[]): the same values, read back alike;
# - a default on a list column (`notes VARCHAR[] DEFAULT []`): every insert gives one.
_PRIMARY_KEY_CLAUSE = re.compile(r",\s*PRIMARY KEY\s*\([^)]*\)", re.I)
_PRIMARY_KEY_INLINE = re.compile(r"\s+PRIMARY KEY\b", re.I)
_FIXED_ARRAY = re.compile(r"\b(\w+)\[\d+\]")
_LIST_DEFAULT = re.compile(r"\s+DEFAULT\s+\[\s*\]", re.I)


def _drop_checks(sql: str) -> str:
    """``sql`` without its ``CHECK (...)`` clauses (balanced parentheses)."""
    out, i = [], 0
    for found in re.finditer(r"\s+CHECK\s*\(", sql, re.I):
        if found.start() < i:
            continue
        depth, j = 1, found.end()
        while depth:
            depth += {"(": 1, ")": -1}.get(sql[j], 0)
            j += 1
        out.append(sql[i : found.start()])
        i = j
    return "".join(out) + sql[i:]


def lake_ddl(sql: str) -> str:
    """A migration's SQL as a DuckLake catalog takes it (see above)."""
    sql = _PRIMARY_KEY_CLAUSE.sub("", sql)
    sql = _PRIMARY_KEY_INLINE.sub(" NOT NULL", sql)
    sql = _FIXED_ARRAY.sub(r"\1[]", sql)
    sql = _LIST_DEFAULT.sub("", sql)
    return _drop_checks(sql)


def _conflict(error: BaseException) -> bool:
    """Whether ``error`` is a lake's commit refused for a snapshot committed meanwhile."""
    return isinstance(error, duckdb.TransactionException) or (
        isinstance(error, duckdb.Error) and "conflict" in str(error).lower()
    )


# A conflicting commit is run again this many times, after a random wait of up to
# CONFLICT_WAIT_S * attempt (so that writers who collided do not collide again in step).
CONFLICT_ATTEMPTS = 20
CONFLICT_WAIT_S = 0.05


def transact(
    con: duckdb.DuckDBPyConnection,
    body: Callable[[duckdb.DuckDBPyConnection], T],
    wait_s: float = LOCK_WAIT_S,
) -> T:
    """``body(con)`` in one transaction; on a lake, run again from the start when its commit
    conflicts with another writer's, or when PostgreSQL dropped the connection (a restart:
    DuckDB connects again by itself), for up to ``wait_s``. Never half-applied: a failed attempt
    is rolled back whole. Every body is written to be run again (a stage's rows are replaced, a
    registration inserts what is not there yet). A DuckDB file has one writer at a time, so
    nothing conflicts there."""
    deadline = time.monotonic() + wait_s
    attempt = 0
    while True:
        attempt += 1
        try:
            with transaction(con):
                return body(con)
        except duckdb.Error as error:
            lost = _unreachable(error)
            if not (lost or _conflict(error)) or attempt == CONFLICT_ATTEMPTS and not lost:
                raise
            if time.monotonic() > deadline:
                if lost:
                    raise CatalogUnreachable(
                        f"PostgreSQL did not answer for {wait_s:.0f} s ({error_line(error)})"
                    ) from error
                raise
            wait = 1.0 if lost else random.uniform(0, CONFLICT_WAIT_S * attempt)
        time.sleep(wait)


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
    versions applied. On a lake the DDL is `lake_ddl`'s, and a migration another process
    committed first is skipped, not applied twice (`transact` runs it again, and it finds it
    applied)."""
    ddl = lake_ddl if is_lake(con) else (lambda sql: sql)

    def create_table(c: duckdb.DuckDBPyConnection) -> None:
        c.execute(
            ddl(
                "CREATE TABLE IF NOT EXISTS schema_migrations (version INTEGER PRIMARY KEY, "
                "name VARCHAR NOT NULL, applied_at TIMESTAMP NOT NULL)"
            )
        )

    transact(con, create_table)
    applied = {row[0] for row in con.execute("SELECT version FROM schema_migrations").fetchall()}
    done = []
    for version, name, sql in migrations():
        if version not in applied and _apply_once(
            con,
            ddl(sql),
            ("SELECT 1 FROM schema_migrations WHERE version = ?", [version]),
            ("INSERT INTO schema_migrations VALUES (?, ?, ?)", [version, name, utcnow()]),
        ):
            done.append(version)
    staged = set()
    if _STAGE_MIGRATIONS:
        staged = set(con.execute("SELECT stage, version FROM stage_migrations").fetchall())
    for stage, folder in _STAGE_MIGRATIONS.items():
        for version, name, sql in _read_migrations(folder):
            if (stage, version) not in staged:
                _apply_once(
                    con,
                    ddl(sql),
                    (
                        "SELECT 1 FROM stage_migrations WHERE stage = ? AND version = ?",
                        [stage, version],
                    ),
                    (
                        "INSERT INTO stage_migrations VALUES (?, ?, ?, ?)",
                        [stage, version, name, utcnow()],
                    ),
                )
    return done


def _apply_once(
    con: duckdb.DuckDBPyConnection,
    sql: str,
    seen: tuple[str, list],
    record: tuple[str, list],
) -> bool:
    """Apply migration ``sql`` and ``record`` it, in one transaction, unless the query ``seen``
    finds it applied already (by another process meanwhile: `transact` may run this again after
    a conflict); whether it was applied here."""

    def apply(c: duckdb.DuckDBPyConnection) -> bool:
        if c.execute(*seen).fetchone():
            return False
        c.execute(sql)
        c.execute(*record)
        return True

    return transact(con, apply)


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
    path: Path | Lake, *, read_only: bool = False, wait_s: float = LOCK_WAIT_S
) -> Iterator[duckdb.DuckDBPyConnection]:
    """A connection to the database at ``path`` (a DuckDB file, or a `Lake`), migrated when
    writable, closed on exit.

    A read-only connection to a file that does not exist yet raises ``FileNotFoundError``. One
    to a file whose schema is behind this Ringside's (a process killed while it created the
    file, between DuckDB's first write and the migrations' commit; or a file of an older
    version) has it migrated first, through a writable connection, so that readers never meet
    a table that is not there yet.
    """
    if read_only and not path.exists():
        raise FileNotFoundError(f"{path}: no database yet (process a video first)")
    if isinstance(path, Lake):
        with _lake_connection(path, read_only=read_only, wait_s=wait_s) as con:
            yield con
        return
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
def _lake_connection(
    lake: Lake, *, read_only: bool, wait_s: float
) -> Iterator[duckdb.DuckDBPyConnection]:
    """`connect` for a lake: no process lock (each connection is its own in-memory DuckDB), and
    a reader finding the schema behind migrates it first, as for a file."""
    con = _open_lake(lake, read_only=read_only, wait_s=wait_s)
    try:
        if read_only and not _migrated(con):
            con.close()
            con = _open_lake(lake, read_only=False, wait_s=wait_s)
            migrate(con)
            con.close()
            con = _open_lake(lake, read_only=True, wait_s=wait_s)
        elif not read_only:
            migrate(con)
        yield con
    except RuntimeError as error:
        if str(error) == "Query interrupted":
            raise Interrupted(f"a query on {lake} was stopped by a signal") from None
        raise
    finally:
        con.close()


@contextmanager
def transaction(con: duckdb.DuckDBPyConnection) -> Iterator[duckdb.DuckDBPyConnection]:
    """Everything inside commits together or not at all."""
    con.begin()
    try:
        yield con
        con.commit()
    except BaseException:
        # A query a signal interrupted may go on running on DuckDB's threads, and the rollback
        # waits for it to end: 71-79 s for 2 of 8 counts over a range interrupted after 1 s
        # (DuckDB 1.4), none of 37 when interrupted here first (the next query is unaffected).
        con.interrupt()
        # A commit that failed (a lake's conflict) has ended the transaction already; a lake's
        # PostgreSQL connection lost (a restart) fails the rollback too ("Failed to execute
        # query "ROLLBACK": ", and nothing more), which must not hide the error that says why.
        with contextlib.suppress(duckdb.Error):
            con.rollback()
        raise


def utcnow() -> datetime:
    return datetime.now(UTC).replace(tzinfo=None)
