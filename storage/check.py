"""What `ringside check` finds damaged in a data directory, and what `--repair` does about it.

The database is the source of truth, so a stage output is damaged when any of its rows cannot be
read back (DuckDB's block checksums surface only on a full read) or a file it names is missing
from the artifact store or no longer hashes to its name. Every block of the file is also checked
against its checksum (`storage.blocks`), for damage no query reads (free space), and every file
of the store is hashed, named by a row or not. Repairing removes damaged outputs, as if never
computed, so that the next `process` or `rerun` computes them again (a stage whose output the
database no longer has recomputes whatever Prefect's cache remembers): every row that reads back
is copied into a new file, the damaged one kept beside it, and corrupt files are quarantined
(`repair`). Rows of the tables that register videos and record runs that sat in a damaged block
are lost; the next `process` registers its videos again. Run it while no other command uses the
data directory.
"""

from __future__ import annotations

import contextlib
import re
import shutil
import sqlite3
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import duckdb

from storage.artifacts import NotAnArtifact, artifact_path, corrupt_files, quarantine
from storage.blocks import UnexpectedLayout, damaged_blocks
from storage.db import connect, error_line, transaction
from storage.files import SCRATCH, TEMPORARY
from storage.records import process_alive

# A stage's output tables are named "<stage>_..." and keyed by (key, video_id) as
# `stage_outputs` is (train: video_id the dataset, key the run; evaluate: video_id the run), so
# a rerun recomputes their rows. These tables of storage's own are keyed alike but hold no
# stage's rows: the record of every output, its metrics and runs, and the datasets' members.
NOT_OUTPUTS = ("stage_outputs", "stage_metrics", "stage_runs", "dataset_members")
# What a problem that is no stage output's is of.
NOT_STAGES = ("database", "artifacts", "prefect")
# A temporary file whose name does not say its writer (an older version's) and is older than
# this was left by a process that is gone.
STALE_TEMP_S = 600.0


@dataclass(frozen=True)
class Problem:
    """One thing damaged: a stage output (``stage``, ``video_id``, ``key``), or, with ``stage``
    "database", "artifacts" or "prefect" (Prefect's own database), something no rerun
    recomputes."""

    stage: str
    video_id: str | None
    key: str | None
    what: str
    # A corrupt artifact file: what `repair` quarantines (found once, by `scan`'s hashing).
    path: Path | None = None

    @property
    def output(self) -> tuple[str, str, str] | None:
        return None if self.stage in NOT_STAGES else (self.stage, self.video_id, self.key)


def _tables(con: duckdb.DuckDBPyConnection, database: str | None = None) -> dict[str, list[str]]:
    """Every table of the connection's database (or of the attached ``database``), with its
    columns."""
    tables: dict[str, list[str]] = {}
    for table, column in con.execute(
        "SELECT table_name, column_name FROM duckdb_columns() "
        "WHERE NOT internal AND database_name = coalesce(?, current_database()) "
        "ORDER BY table_name, column_index",
        [database],
    ).fetchall():
        tables.setdefault(table, []).append(column)
    return tables


def _stage_of(table: str, columns: list[str]) -> str | None:
    """The stage whose outputs the table holds; None for the tables that register videos,
    datasets and runs (`dataset_members` joins outputs into datasets, it holds none)."""
    keyed = {"key", "video_id"} <= set(columns)
    return table.partition("_")[0] if keyed and table not in NOT_OUTPUTS else None


def _read(con: duckdb.DuckDBPyConnection, table: str, where: str = "", params=()) -> None:
    """Read every column of the rows (hashing them), so that damaged blocks raise."""
    con.execute(f"SELECT count(*), bit_xor(hash(t)) FROM {table} t {where}", list(params))


def _outputs(
    con: duckdb.DuckDBPyConnection, stage: str, table: str, schema: str = ""
) -> list[tuple[str, str]]:
    """(video_id, key) of the stage's outputs with rows in ``table`` or committed (only the
    committed ones when the table's key columns are unreadable themselves); ``schema`` is the
    attached database's prefix ("old.") where the tables are another file's."""
    committed = f"SELECT video_id, key FROM {schema}stage_outputs WHERE stage = ?"
    try:
        rows = con.execute(
            f"SELECT DISTINCT video_id, key FROM {table} UNION {committed} ORDER BY ALL", [stage]
        ).fetchall()
    except duckdb.Error:
        rows = con.execute(f"{committed} ORDER BY ALL", [stage]).fetchall()
    return [tuple(row) for row in rows]


def _artifact_problem(artifacts: Path, corrupt: Mapping[str, Path], name: str) -> str | None:
    try:
        path = artifact_path(artifacts, name)
    except NotAnArtifact:
        return f"names {name!r}, a path outside the artifact store"
    if not path.exists():
        return f"artifact {name[:12]}… is missing"
    if name in corrupt:
        return f"artifact {name[:12]}… is corrupt (its bytes do not hash to its name)"
    return None


def stale_temporaries(artifacts: Path, now: float | None = None) -> list[Path]:
    """Temporary files of interrupted writes in the artifact store: their writer (named in the
    file's name, `storage.files.write_atomic`) is gone, or, for a name without one, they are
    older than STALE_TEMP_S."""
    now = time.time() if now is None else now
    if not artifacts.exists():
        return []
    stale = []
    for path in artifacts.glob(f"*/{TEMPORARY}*"):
        writer = path.name.removeprefix(TEMPORARY).split("-", 1)[0]
        if writer.isdigit():
            gone = not process_alive(int(writer))
        else:
            gone = now - path.stat().st_mtime > STALE_TEMP_S
        if gone and path.is_file():
            stale.append(path)
    return sorted(stale)


def orphaned_scratch(root: Path | None = None) -> list[Path]:
    """Scratch folders (`storage.files.scratch_dir`) in the system's temporary directory, or
    ``root``, whose process is gone: a kill left them."""
    root = Path(tempfile.gettempdir()) if root is None else root
    orphans = []
    for path in root.glob(f"{SCRATCH}*"):
        parts = path.name.split("-")
        if len(parts) == 4 and parts[2].isdigit() and not process_alive(int(parts[2])):
            orphans.append(path)
    return sorted(orphans)


def remove_stale_temporaries(artifacts: Path, scratch_root: Path | None = None) -> list[Path]:
    """Delete the `stale_temporaries` of the artifact store and the `orphaned_scratch`
    folders; the paths deleted."""
    stale = stale_temporaries(artifacts)
    for path in stale:
        path.unlink(missing_ok=True)
    orphans = orphaned_scratch(scratch_root)
    for path in orphans:
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
    return stale + orphans


def scan(
    db: Path,
    artifacts: Path | None,
    progress: Callable[[str], None] | None = None,
    prefect_db: Path | None = None,
) -> list[Problem]:
    """Everything damaged in the database at ``db``, the artifact store at ``artifacts`` (None:
    the database alone, its tables read back but no file looked for) and Prefect's own SQLite
    database ``prefect_db`` (its run history; None: not looked at).

    Then every block of the database file is checked against its checksum
    (`storage.blocks`), for damage no table read reaches: free space, metadata, rows past the
    first damaged block of a table. ``progress(table)`` is called as each table is read.
    """
    problems: list[Problem] = []
    prefect = _prefect_problems(prefect_db)
    if not db.exists():  # nothing of ours yet, but Prefect's history may be there
        return prefect
    # Every file is hashed once, named by a row or not (Prefect's cache names pose chunks).
    corrupt = {p.name: p for p in corrupt_files(artifacts)} if artifacts is not None else {}
    named: set[str] = set()
    try:
        with connect(db, read_only=True) as con:
            for table, columns in _tables(con).items():
                if progress is not None:
                    progress(table)
                problems += _table_problems(con, artifacts, corrupt, named, table, columns)
            # Still holding the lock that keeps writers out: every block, read or not by a query.
            problems += _block_problems(db, problems)
    except duckdb.Error as error:
        what = f"{db} cannot be opened: {error_line(error)}"
        return [Problem("database", None, None, what), *prefect]
    if artifacts is not None:
        problems += [
            Problem("artifacts", None, None, f"{path} is left over from an interrupted write")
            for path in stale_temporaries(artifacts)
        ]
        problems += [
            Problem(
                "artifacts", None, None, f"artifact {name[:12]}… is corrupt (no row names it)", path
            )
            for name, path in sorted(corrupt.items())
            if name not in named
        ]
    return problems + prefect


def _block_problems(db: Path, found: list[Problem]) -> list[Problem]:
    """The blocks of the file ``db`` whose checksum fails, but for those the ``found`` problems
    name already (a table read names the block's first byte, `storage.db.error_line`)."""
    try:
        damaged = damaged_blocks(db)
    except UnexpectedLayout as error:
        return [Problem("database", None, None, f"its blocks cannot be verified: {error}")]
    named = {int(n) for problem in found for n in re.findall(r"bytes from (\d+)", problem.what)}
    return [
        Problem(
            "database",
            None,
            None,
            f"the block at byte {offset} of {db.name} fails its checksum (free space, metadata "
            "or rows past a table's first damaged block): --repair copies what reads back",
        )
        for offset in damaged
        if offset not in named
    ]


def _table_problems(
    con: duckdb.DuckDBPyConnection,
    artifacts: Path | None,
    corrupt: Mapping[str, Path],
    named: set[str],
    table: str,
    columns: list[str],
) -> list[Problem]:
    """What is damaged in ``table``: rows that do not read back, and files named by its
    ``artifact`` column that are missing or among the ``corrupt`` (added to ``named``)."""
    stage = _stage_of(table, columns)
    try:
        _read(con, table)
        unreadable = None
    except duckdb.Error as error:
        unreadable = error_line(error)
    if unreadable is not None and stage is None:
        return [Problem("database", None, None, f"table {table} is damaged: {unreadable}")]
    if unreadable is not None:
        found = []
        for video_id, key in _outputs(con, stage, table):
            try:
                _read(con, table, "WHERE key = ? AND video_id = ?", (key, video_id))
            except duckdb.Error as error:
                what = f"rows of {table} are damaged: {error_line(error)}"
                found.append(Problem(stage, video_id, key, what))
        return found or [Problem("database", None, None, f"table {table} is damaged: {unreadable}")]
    if stage is None or "artifact" not in columns or artifacts is None:
        return []
    found = []
    for video_id, key, name in con.execute(
        f"SELECT DISTINCT video_id, key, artifact FROM {table} ORDER BY ALL"
    ).fetchall():
        named.add(name)
        problem = _artifact_problem(artifacts, corrupt, name)
        if problem is not None:
            found.append(Problem(stage, video_id, key, f"{table}: {problem}", corrupt.get(name)))
    return found


def _prefect_problems(path: Path | None) -> list[Problem]:
    """Prefect's SQLite database at ``path`` as SQLite's own quick check (read only) finds it:
    [] when it is sound, absent or not looked at."""
    if path is None or not path.exists():
        return []
    try:
        with contextlib.closing(sqlite3.connect(f"{path.as_uri()}?mode=ro", uri=True)) as con:
            found = [row[0] for row in con.execute("PRAGMA quick_check").fetchall()]
    except sqlite3.DatabaseError as error:
        found = [str(error)]
    if found == ["ok"]:
        return []
    what = f"Prefect's database {path} is damaged ({'; '.join(found[:3])})"
    return [Problem("prefect", None, None, f"{what}; it holds run history only")]


def _set_aside(path: Path, companions: tuple[str, ...]) -> Path:
    """Rename a damaged database file and its ``companions`` (suffixes: a WAL) to
    ``<name>.damaged-<time>``, so that its owner starts a new one; returns the new name."""
    aside = path.with_name(f"{path.name}.damaged-{time.strftime('%Y%m%d-%H%M%S')}")
    for suffix in companions:
        companion = path.with_name(path.name + suffix)
        if companion.exists():
            companion.rename(aside.with_name(aside.name + suffix))
    path.rename(aside)
    return aside


def repair(
    db: Path, artifacts: Path, problems: Iterable[Problem], prefect_db: Path | None = None
) -> list[str]:
    """A new database file holding every row that reads back, but for the damaged outputs among
    ``problems``; the damaged file is kept beside it (``<name>.damaged-<time>``). The corrupt
    artifact files among ``problems`` are quarantined, so that recomputing their outputs
    writes them anew, and stale temporary files go too. A damaged Prefect database
    (``prefect_db``) is set aside the same way, and Prefect starts a new one. One line per thing
    done.

    The rows are copied rather than the damaged file written to: DuckDB stops with a fatal
    error when a write touches a damaged block (seen on a file with 19 flipped blocks). A
    table's rows are copied output by output, or, for the tables that register videos and
    record runs, in halving ranges of rows, so that a damaged block loses only the rows it
    holds.
    """
    problems = list(problems)
    done = []
    if prefect_db is not None and any(p.stage == "prefect" for p in problems):
        aside = _set_aside(prefect_db, ("-wal", "-shm"))
        done.append(f"set Prefect's database aside as {aside}; the next command starts anew")
    if all(p.stage == "prefect" for p in problems):
        return done
    damaged = {p.output for p in problems if p.output is not None}
    fresh = db.with_name(db.name + ".repairing")
    _unlink_with_wal(fresh)
    try:
        with connect(fresh) as con:  # migrated: every table, empty
            con.execute(f"ATTACH '{_quoted(db)}' AS old (READ_ONLY)")
            done += _copy(con, damaged)
            con.execute("DETACH old")
            con.execute("CHECKPOINT")
    except duckdb.Error as error:  # not even the catalogue reads back
        _unlink_with_wal(fresh)
        with connect(fresh):
            pass
        done.append(
            f"{db} cannot be read at all ({error_line(error)}): a new, empty database "
            "replaces it and the next `ringside process` computes everything again"
        )
    aside = _set_aside(db, (".wal",))
    fresh.rename(db)
    done.append(f"kept the damaged file as {aside}")
    done += [
        f"moved the corrupt {path.name[:12]}… aside to {quarantine(artifacts, path)}"
        for path in sorted({p.path for p in problems if p.path is not None})
        if path.exists()
    ]
    done += [f"removed {path}" for path in remove_stale_temporaries(artifacts)]
    return done


def _unlink_with_wal(path: Path) -> None:
    for file in (path, path.with_name(path.name + ".wal")):
        file.unlink(missing_ok=True)


def _quoted(path: Path) -> str:
    return str(path).replace("'", "''")


def _copy(con: duckdb.DuckDBPyConnection, damaged: set[tuple[str, str, str]]) -> list[str]:
    """Copy the attached database ``old`` into this one, but for the ``damaged`` outputs."""
    done = []
    ours = set(_tables(con))
    for table, columns in _tables(con, "old").items():
        if table not in ours or table == "schema_migrations":
            continue
        stage = _stage_of(table, columns)
        insert = f"INSERT INTO main.{table} BY NAME SELECT * FROM old.{table}"
        if stage is not None:
            for video_id, key in _outputs(con, stage, f"old.{table}", "old."):
                if (stage, video_id, key) in damaged:
                    continue
                try:
                    con.execute(f"{insert} WHERE key = ? AND video_id = ?", [key, video_id])
                except duckdb.Error:
                    damaged.add((stage, video_id, key))
            continue
        total = con.execute(f"SELECT count(*) FROM old.{table}").fetchone()[0]
        lost = _copy_rows(con, insert, 0, total)
        if lost:
            done.append(f"lost {lost} of {total} rows of {table} (in damaged blocks)")
    with transaction(con):
        for stage, video_id, key in sorted(damaged):
            for table in ("stage_outputs", "stage_metrics"):
                con.execute(
                    f"DELETE FROM {table} WHERE stage = ? AND video_id = ? AND key = ?",
                    [stage, video_id, key],
                )
            done.append(
                f"left out the damaged {stage} output {key[:12]} of {video_id[:12]}: the next "
                "run computes it again"
            )
    return done


def _copy_rows(con: duckdb.DuckDBPyConnection, insert: str, start: int, end: int) -> int:
    """Copy rows ``start`` to ``end`` (rowid) with ``insert``, halving the range around damaged
    blocks; how many rows could not be read."""
    if end <= start:
        return 0
    try:
        con.execute(f"{insert} WHERE rowid >= ? AND rowid < ?", [start, end])
        return 0
    except duckdb.Error:
        if end - start == 1:
            return 1
        middle = (start + end) // 2
        return _copy_rows(con, insert, start, middle) + _copy_rows(con, insert, middle, end)
