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

Results in a DuckLake catalog (`storage.paths.Lake`) have no file of blocks: their rows are in the
Parquet files the catalog names, each looked for in the shared folder (and read on its own where
its table does not read back), and a file that is missing or damaged is named with the stage
output its rows belong to (the catalog's statistics of its ``key`` and ``video_id`` columns).
Repairing a lake removes the damaged outputs' rows in one transaction, in place (DuckLake keeps
the snapshot before readable by time travel): by DELETE, but for a table that lost a file, which
is made anew from its other rows (DuckLake cannot delete rows from a file it cannot open).
"""

from __future__ import annotations

import contextlib
import re
import shutil
import sqlite3
import tempfile
import time
from collections.abc import Callable, Collection, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import duckdb

from storage.artifacts import NotAnArtifact, artifact_path, corrupt_files, quarantine
from storage.blocks import UnexpectedLayout, damaged_blocks
from storage.db import LAKE_ALIAS, CatalogUnreachable, connect, error_line, transact, transaction
from storage.files import SCRATCH, TEMPORARY
from storage.paths import Lake
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
    # A lake's Parquet file whose rows are lost, and its table: what `repair` deletes the rows
    # of (by the file's name), with the output's other rows.
    table: str | None = None
    data_file: str | None = None

    @property
    def output(self) -> tuple[str, str, str] | None:
        return None if self.stage in NOT_STAGES else (self.stage, self.video_id, self.key)


def table_columns(
    con: duckdb.DuckDBPyConnection, database: str | None = None
) -> dict[str, list[str]]:
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
    db: Path | Lake,
    artifacts: Path | None,
    progress: Callable[[str], None] | None = None,
    prefect_db: Path | None = None,
) -> list[Problem]:
    """Everything damaged in the database at ``db`` (a DuckDB file or a `Lake`), the artifact
    store at ``artifacts`` (None: the database alone, its tables read back but no file looked
    for) and Prefect's own SQLite database ``prefect_db`` (its run history; None: not looked
    at).

    Then every block of a database file is checked against its checksum (`storage.blocks`),
    for damage no table read reaches: free space, metadata, rows past the first damaged block
    of a table; of a lake, every Parquet file its catalog names is looked for, and read on its
    own where its table does not read back. ``progress(table)`` is called as each table is
    read.
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
            # A lake has no file of blocks to verify; its rows are in Parquet files, which its
            # tables' reads name when one is missing or damaged.
            lake = isinstance(db, Lake)
            for table, columns in table_columns(con).items():
                if progress is not None:
                    progress(table)
                if lake:
                    found, lost = _lake_table_problems(con, table, columns)
                    problems += found
                    if lost is not None:  # None: the rest of the table cannot be read
                        problems += _artifact_problems(
                            con, artifacts, corrupt, named, table, columns, lost
                        )
                else:
                    problems += _table_problems(con, artifacts, corrupt, named, table, columns)
            if not lake:
                # Still holding the lock that keeps writers out: every block, read or not.
                problems += _block_problems(db, problems)
    except (duckdb.Error, CatalogUnreachable) as error:
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


def table_ddl(con: duckdb.DuckDBPyConnection) -> dict[str, str]:
    """Each table of the connection's database, with the statement that makes it."""
    return dict(
        con.execute(
            "SELECT table_name, sql FROM duckdb_tables() WHERE database_name = current_database()"
        ).fetchall()
    )


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
    return _artifact_problems(con, artifacts, corrupt, named, table, columns)


def _artifact_problems(
    con: duckdb.DuckDBPyConnection,
    artifacts: Path | None,
    corrupt: Mapping[str, Path],
    named: set[str],
    table: str,
    columns: list[str],
    lost: Collection[tuple[str, str]] = (),
) -> list[Problem]:
    """The files named by ``table``'s ``artifact`` column that are missing or among the
    ``corrupt`` (added to ``named``); the rows of a lake's ``lost`` outputs (video_id, key),
    whose Parquet files are gone, are left unread."""
    stage = _stage_of(table, columns)
    if stage is None or "artifact" not in columns or artifacts is None:
        return []
    rows, params = _without(table, lost)
    found = []
    for video_id, key, name in con.execute(
        f"SELECT DISTINCT video_id, key, artifact FROM {rows} ORDER BY ALL", params
    ).fetchall():
        named.add(name)
        problem = _artifact_problem(artifacts, corrupt, name)
        if problem is not None:
            found.append(Problem(stage, video_id, key, f"{table}: {problem}", corrupt.get(name)))
    return found


def _without(table: str, outputs: Collection[tuple[str, str]]) -> tuple[str, list[str]]:
    """A lake ``table``'s rows but for those of ``outputs`` (video_id, key), as a FROM item
    that never opens their Parquet files: DuckLake leaves out a file whose statistics rule a
    filter out (its key is the one key <> excludes), but not for an OR, nor by a file's name
    (it opens the file first), so the rows are a UNION ALL of plain conjunctions."""
    if not outputs:
        return table, []
    keys = sorted({key for _, key in outputs})
    parts = [f"SELECT * FROM {table} WHERE " + " AND ".join(["key <> ?"] * len(keys))]
    params = list(keys)
    for key in keys:
        videos = sorted(video_id for video_id, k in outputs if k == key)
        parts.append(
            f"SELECT * FROM {table} WHERE key = ? AND "
            + " AND ".join(["video_id <> ?"] * len(videos))
        )
        params += [key, *videos]
    return f"({' UNION ALL '.join(parts)})", params


def _lake_table_problems(
    con: duckdb.DuckDBPyConnection, table: str, columns: list[str]
) -> tuple[list[Problem], set[tuple[str, str]] | None]:
    """What is damaged in a lake's ``table``, and the outputs (video_id, key) whose rows are in
    its lost Parquet files (None where the rest of the table cannot be read without them).

    Every data file (and file of deleted rows) the catalog names is looked for, at the size it
    recorded; every row is read back, but for the lost files'; when that read fails, each file
    is read on its own, to name the one that does not decode."""
    files = con.execute(
        "SELECT data_file, data_file_size_bytes, delete_file, delete_file_size_bytes "
        "FROM ducklake_list_files(?, ?) ORDER BY data_file",
        [LAKE_ALIAS, table],
    ).fetchall()
    faults = {}
    for data_file, size, delete_file, delete_size in files:
        fault = _file_fault(data_file, size)
        if fault is None and delete_file is not None:
            fault = _file_fault(delete_file, delete_size)
            fault = None if fault is None else f"(its file of deleted rows) {fault}"
        if fault is not None:
            faults[data_file] = fault
    if not faults:
        try:
            _read(con, table)
            return [], set()
        except duckdb.Error as error:
            unreadable = error_line(error)
        faults = _undecodable(con, files)
        if not faults:
            what = f"table {table} is damaged: {unreadable}"
            return [Problem("database", None, None, what)], None
    problems = _lost_file_problems(con, table, columns, faults)
    if any(p.output is None for p in problems):  # a file of rows no statistics tell
        return problems, None
    lost = {(p.video_id, p.key) for p in problems}
    try:
        rows, params = _without(table, lost)
        _read(con, rows, params=params)
    except duckdb.Error as error:
        what = f"table {table} is damaged: {error_line(error)}"
        return [*problems, Problem("database", None, None, what)], None
    return problems, lost


def _undecodable(con: duckdb.DuckDBPyConnection, files: list[tuple]) -> dict[str, str]:
    """The data files among ``files`` (rows of `ducklake_list_files`) that do not read whole,
    or whose file of deleted rows does not: file -> why."""
    faults = {}
    for data_file, _, delete_file, _ in files:
        for path in filter(None, (data_file, delete_file)):
            try:
                con.execute("SELECT count(*), bit_xor(hash(t)) FROM read_parquet(?) t", [path])
            except duckdb.Error as error:
                whose = "" if path == data_file else "(its file of deleted rows) "
                faults[data_file] = f"{whose}does not read: {error_line(error)}"
                break
    return faults


def _file_fault(path: str, size: int | None) -> str | None:
    """Why the Parquet file at ``path`` is not as the catalog recorded it (missing, or another
    size), or None."""
    try:
        found = Path(path).stat().st_size
    except FileNotFoundError:
        return "is missing"
    if size is not None and found != size:
        return f"has {found} bytes where the catalog recorded {size}"
    return None


def _lost_file_problems(
    con: duckdb.DuckDBPyConnection, table: str, columns: list[str], faults: Mapping[str, str]
) -> list[Problem]:
    """A problem per lost Parquet file of ``table`` (``faults``: file -> what is wrong with
    it): of the stage output its rows are, as the catalog's statistics of the file's ``key``
    and ``video_id`` columns tell (a store writes each output's rows apart); of the database
    where they tell no one output (a compacted file) or the table holds no stage's outputs:
    then no rerun gives the rows back, a backup does."""
    stage = _stage_of(table, columns)
    held = _file_outputs(con, table) if stage is not None else {}
    found = []
    for data_file, fault in sorted(faults.items()):
        what = f"{table}: Parquet file {Path(data_file).name} {fault}"
        output = held.get(Path(data_file).name)
        if output is not None:
            video_id, key = output
            found.append(Problem(stage, video_id, key, what, table=table, data_file=data_file))
            continue
        whose = "of no one output its statistics tell" if stage else "rows no rerun gives back"
        what = f"{what} ({whose})"
        found.append(Problem("database", None, None, what, table=table, data_file=data_file))
    return found


def _file_outputs(con: duckdb.DuckDBPyConnection, table: str) -> dict[str, tuple[str, str]]:
    """The (video_id, key) of the one output each current Parquet file of ``table`` holds rows
    of, by file name (the catalog names a file relative to its table's folder), as the
    catalog's statistics tell it: the file's lowest key is its highest, and so its video."""
    meta = f"__ducklake_metadata_{LAKE_ALIAS}"
    stats = con.execute(
        f"""SELECT f.path, c.column_name, s.min_value, s.max_value
        FROM {meta}.ducklake_data_file f
        JOIN {meta}.ducklake_table t ON t.table_id = f.table_id AND t.end_snapshot IS NULL
        JOIN {meta}.ducklake_file_column_stats s ON s.data_file_id = f.data_file_id
        JOIN {meta}.ducklake_column c ON c.column_id = s.column_id AND c.table_id = f.table_id
            AND c.end_snapshot IS NULL
        WHERE f.end_snapshot IS NULL AND t.table_name = ? AND c.column_name IN ('key', 'video_id')
        """,
        [table],
    ).fetchall()
    single: dict[str, dict[str, str]] = {}
    for path, column, low, high in stats:
        if low is not None and low == high:
            single.setdefault(Path(path).name, {})[column] = low
    return {
        name: (one["video_id"], one["key"])
        for name, one in single.items()
        if set(one) == {"key", "video_id"}
    }


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
    db: Path | Lake, artifacts: Path, problems: Iterable[Problem], prefect_db: Path | None = None
) -> list[str]:
    """A new database file holding every row that reads back, but for the damaged outputs among
    ``problems``; the damaged file is kept beside it (``<name>.damaged-<time>``). A lake's
    damaged outputs are deleted from it instead, in one transaction (`_repair_lake`). The
    corrupt artifact files among ``problems`` are quarantined, so that recomputing their
    outputs writes them anew, and stale temporary files go too. A damaged Prefect database
    (``prefect_db``) is set aside the same way, and Prefect starts a new one. One line per
    thing done, or refused.

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
    # A lake is written in place: each commit is a new snapshot, the one before stays readable
    # (time travel), and a DELETE of a lost file's rows does not open the file. A DuckDB file
    # is copied: a write that touches a damaged block is fatal.
    done += _repair_lake(db, problems) if isinstance(db, Lake) else _repair_file(db, problems)
    done += [
        f"moved the corrupt {path.name[:12]}… aside to {quarantine(artifacts, path)}"
        for path in sorted({p.path for p in problems if p.path is not None})
        if path.exists()
    ]
    done += [f"removed {path}" for path in remove_stale_temporaries(artifacts)]
    return done


def _repair_file(db: Path, problems: list[Problem]) -> list[str]:
    """`repair` of a DuckDB file: every row that reads back copied into a new file, but for the
    damaged outputs; the damaged file kept beside it."""
    done = []
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
    return done


def _repair_lake(lake: Lake, problems: list[Problem]) -> list[str]:
    """`repair` of a lake, in one transaction: every row of each damaged output deleted, in
    every table of its stage, and its record and metrics. A table that lost a Parquet file is
    made anew from its other rows instead: DuckLake cannot delete rows from a file it cannot
    open, and only dropping a table drops its files unopened (the rows are read around the
    lost files by `_without`). What no rerun gives back (a lost file of rows that are no
    stage's output, or a table that does not read back) is refused, one line each: a backup
    has those rows (`ringside restore`)."""
    refused = [
        f"cannot repair {p.what}: `ringside restore` puts a backup's rows back"
        for p in problems
        if p.stage == "database"
    ]
    damaged = sorted({p.output for p in problems if p.output is not None})
    remade = sorted({p.table for p in problems if p.output is not None and p.data_file})
    if not damaged:
        return refused
    with connect(lake) as con:
        tables = table_columns(con)
        ddl = table_ddl(con)

        def remove(c: duckdb.DuckDBPyConnection) -> int:
            before = lake_snapshot(c)
            for table in remade:
                stage = _stage_of(table, tables[table])
                kept, params = _without(table, [(v, k) for s, v, k in damaged if s == stage])
                # Held in this process's memory while the table is dropped and made again.
                c.execute(f"CREATE TEMP TABLE _kept AS SELECT * FROM {kept} t", params)
                c.execute(f"DROP TABLE {table}")
                c.execute(ddl[table])
                c.execute(f"INSERT INTO {table} BY NAME SELECT * FROM temp._kept")
                c.execute("DROP TABLE temp._kept")
            for stage, video_id, key in damaged:
                for table, columns in tables.items():
                    if table not in remade and _stage_of(table, columns) == stage:
                        c.execute(
                            f"DELETE FROM {table} WHERE key = ? AND video_id = ?", [key, video_id]
                        )
                for table in ("stage_outputs", "stage_metrics"):
                    c.execute(
                        f"DELETE FROM {table} WHERE stage = ? AND video_id = ? AND key = ?",
                        [stage, video_id, key],
                    )
            return before

        before = transact(con, remove)
        after = lake_snapshot(con)
    done = [
        f"removed the damaged {stage} output {key[:12]} of {video_id[:12]}: the next run "
        "computes it again"
        for stage, video_id, key in damaged
    ]
    done += [f"made {table} anew from its rows in the Parquet files left" for table in remade]
    done.append(f"committed as the lake's snapshot {after} (the damaged one, {before}, is kept)")
    return done + refused


def lake_snapshot(con: duckdb.DuckDBPyConnection) -> int:
    """The lake's snapshot ``con`` reads (in a transaction: the one it started from)."""
    return con.execute(f"SELECT id FROM {LAKE_ALIAS}.current_snapshot()").fetchone()[0]


def _unlink_with_wal(path: Path) -> None:
    for file in (path, path.with_name(path.name + ".wal")):
        file.unlink(missing_ok=True)


def _quoted(path: Path) -> str:
    return str(path).replace("'", "''")


def _copy(con: duckdb.DuckDBPyConnection, damaged: set[tuple[str, str, str]]) -> list[str]:
    """Copy the attached database ``old`` into this one, but for the ``damaged`` outputs."""
    done = []
    ours = set(table_columns(con))
    for table, columns in table_columns(con, "old").items():
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
