"""A consistent copy of the database (`ringside backup`), and putting one back (`ringside restore`).

The copy is taken while this process holds DuckDB's write lock, after a checkpoint has moved the
write-ahead log into the file, so no writer changes it mid-copy and the copy is one moment of the
database. A lake (`storage.paths.Lake`) is copied as one of its snapshots: its tables, as they were
at that snapshot, into a new DuckDB file; restoring into a lake replaces its tables' rows in one
transaction, and the snapshot it replaced stays readable by DuckLake's time travel. The artifact
store is not copied: its files are named by their hashes and never change, and `ringside check`
says which the restored database names but cannot find.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import duckdb

from storage.check import Problem, lake_snapshot, scan, table_columns, table_ddl
from storage.db import LAKE_ALIAS, connect, error_line, transact, transaction, utcnow
from storage.files import sha256_file, write_atomic
from storage.paths import Lake

DATABASE = "ringside.duckdb"
MANIFEST = "backup.json"
# The record of the migrations a database's tables went through: a database whose rows a
# backup's replace keeps its own, since its tables are the ones those migrations made.
SCHEMA_TABLES = ("schema_migrations", "stage_migrations")


def backup(db: Path | Lake, out: Path) -> dict:
    """Copy the database at ``db`` (a file, or a `Lake` at its current snapshot) into the folder
    ``out`` (created; a backup already there is replaced only once the new one is complete).
    Returns the manifest written beside it (with a lake's, the snapshot copied).

    The copy is read back as `ringside check` reads a database (every row, every block's
    checksum) before it replaces anything: a damaged one raises ValueError and is deleted.
    """
    out.mkdir(parents=True, exist_ok=True)
    partial = out / f".{DATABASE}.partial"
    try:
        # A lake is no file to copy: its tables are read at one snapshot into a new file.
        if isinstance(db, Lake):
            snapshot, tables = _copy_lake(db, partial)
        else:
            snapshot, tables = None, _copy_file(db, partial)
        # Damage copies silently and would otherwise show only at `restore`.
        broken = scan(partial, None)
        if broken:
            raise ValueError(
                f"no backup written: {db} does not copy whole ({len(broken)} problem(s), "
                f"`ringside check` names them), first: {broken[0].what}"
            )
        manifest = {
            "source": str(db),
            "taken_at": utcnow().isoformat(timespec="seconds"),
            "sha256": sha256_file(partial),
            "bytes": partial.stat().st_size,
            "rows": tables,
        }
        if snapshot is not None:
            manifest["snapshot"] = snapshot
        partial.rename(out / DATABASE)
    finally:
        partial.unlink(missing_ok=True)  # left only by a failure: the copy was renamed
    write_atomic(out / MANIFEST, json.dumps(manifest, indent=2).encode())
    return manifest


def _copy_file(db: Path, partial: Path) -> dict[str, int]:
    """The file ``db`` copied to ``partial`` under its write lock; its tables' row counts."""
    with connect(db) as con:  # holds the write lock until the copy is done
        con.execute("CHECKPOINT")
        shutil.copyfile(db, partial)
        return {
            table: con.execute(f"SELECT count(*) FROM {table}").fetchone()[0]
            for (table,) in con.execute(
                "SELECT table_name FROM duckdb_tables() ORDER BY table_name"
            ).fetchall()
        }


def _copy_lake(lake: Lake, partial: Path) -> tuple[int, dict[str, int]]:
    """The lake's tables (as its catalog defines them: no keys, lists for arrays) and their rows
    at its current snapshot, into a new DuckDB file at ``partial``; (the snapshot, the tables'
    row counts). Writers go on meanwhile: every table is read at that one snapshot."""
    for path in (partial, partial.with_name(partial.name + ".wal")):
        path.unlink(missing_ok=True)
    with connect(lake, read_only=True) as con:
        con.execute(f"ATTACH '{_quoted(partial)}' AS backup")
        try:
            with transaction(con):
                snapshot = lake_snapshot(con)
                con.execute(f"COPY FROM DATABASE {LAKE_ALIAS} TO backup (SCHEMA)")
                tables = sorted(table_columns(con, "backup"))
                for table in tables:
                    con.execute(
                        f"INSERT INTO backup.{table} BY NAME SELECT * FROM {LAKE_ALIAS}.{table} "
                        f"AT (VERSION => {snapshot})"
                    )
            counts = {
                table: con.execute(f"SELECT count(*) FROM backup.{table}").fetchone()[0]
                for table in tables
            }
            con.execute("CHECKPOINT backup")
        finally:
            con.execute("DETACH backup")
    return snapshot, counts


def _quoted(path: Path) -> str:
    return str(path).replace("'", "''")


def restore(
    db: Path | Lake, artifacts: Path, backup_dir: Path
) -> tuple[Path | int | None, list[Problem]]:
    """Put the backup in ``backup_dir`` in place of the database at ``db``, whose file (if any)
    is kept beside it as ``<name>.replaced-<time>``; a lake's tables get the backup's rows in
    one transaction, the snapshot before kept by DuckLake. Refuses a backup whose bytes are not
    the ones it was taken with or that does not read back whole. Returns (the kept file, or the
    lake's snapshot replaced; the problems `check` finds in the restored database, e.g.
    artifacts gone since the backup)."""
    source = backup_dir / DATABASE
    try:
        manifest = json.loads((backup_dir / MANIFEST).read_text())
    except (OSError, ValueError) as error:
        raise ValueError(
            f"{backup_dir} is not a backup (`ringside backup DIR` makes one): {error}"
        ) from None
    if not source.exists() or sha256_file(source) != manifest.get("sha256"):
        raise ValueError(f"{source} is missing or changed since the backup was taken")
    broken = scan(source, None)
    if broken:
        raise ValueError(f"{source} does not read back: {broken[0].what}")
    # A lake is written in place, in one transaction, and keeps the snapshot it replaces; a
    # file is moved aside and the backup's copy takes its place.
    if isinstance(db, Lake):
        return _restore_lake(db, artifacts, source)
    if "snapshot" in manifest:
        return _restore_lake_backup_into_file(db, artifacts, source)
    aside = _set_aside(db)
    partial = db.with_name(f".{db.name}.restoring")
    shutil.copyfile(source, partial)
    partial.rename(db)
    return aside, scan(db, artifacts)


def _set_aside(db: Path) -> Path | None:
    """The file ``db`` and its write-ahead log renamed ``<name>.replaced-<time>``; the first
    of them kept, or None when there was none."""
    aside = None
    stamp = time.strftime("%Y%m%d-%H%M%S")
    for current in (db, db.with_name(db.name + ".wal")):
        if current.exists():
            kept = current.with_name(f"{current.name}.replaced-{stamp}")
            current.rename(kept)
            aside = aside or kept
    return aside


def _restore_lake(lake: Lake, artifacts: Path, source: Path) -> tuple[int, list[Problem]]:
    """The backup's rows (a lake's or a file's) in place of every table's of ``lake``, in one
    transaction; (the snapshot replaced, the problems `check` finds after)."""
    with connect(lake) as con:  # writable: migrated, every table there
        con.execute(f"ATTACH '{_quoted(source)}' AS backup (READ_ONLY)")
        try:
            ours = table_columns(con)
            theirs = _fitting(table_columns(con, "backup"), ours, source, lake)
            ddl = table_ddl(con)

            def put_back(c: duckdb.DuckDBPyConnection) -> int:
                replaced = lake_snapshot(c)
                for table in sorted(set(ours) - set(SCHEMA_TABLES)):
                    # Made anew rather than emptied: a DELETE opens every Parquet file of the
                    # table, and a lake being restored may have lost some.
                    c.execute(f"DROP TABLE {table}")
                    c.execute(ddl[table])
                    if table in theirs:
                        c.execute(f"INSERT INTO {table} BY NAME SELECT * FROM backup.{table}")
                return replaced

            try:
                replaced = transact(con, put_back)
            except duckdb.Error as error:
                raise ValueError(
                    f"{source} does not fit {lake}'s tables ({error_line(error)}); nothing changed"
                ) from None
        finally:
            con.execute("DETACH backup")
    return replaced, scan(lake, artifacts)


def _restore_lake_backup_into_file(
    db: Path, artifacts: Path, source: Path
) -> tuple[Path | None, list[Problem]]:
    """A lake's backup into the DuckDB file ``db``: its tables are a lake's (no keys, lists for
    arrays), so its rows go into a new, migrated file, which then takes the place of ``db``
    (kept as ``<name>.replaced-<time>``). Refused in one line where they do not fit the file's
    tables (rows a key forbids); nothing is changed then."""
    fresh = db.with_name(f".{db.name}.restoring")
    for path in (fresh, fresh.with_name(fresh.name + ".wal")):
        path.unlink(missing_ok=True)
    try:
        with connect(fresh) as con:  # migrated: every table, empty
            con.execute(f"ATTACH '{_quoted(source)}' AS backup (READ_ONLY)")
            theirs = _fitting(table_columns(con, "backup"), table_columns(con), source, db)
            with transaction(con):
                for table in sorted(set(theirs) - set(SCHEMA_TABLES)):
                    con.execute(f"INSERT INTO {table} BY NAME SELECT * FROM backup.{table}")
            con.execute("DETACH backup")
            con.execute("CHECKPOINT")
    except (duckdb.Error, ValueError) as error:
        for path in (fresh, fresh.with_name(fresh.name + ".wal")):
            path.unlink(missing_ok=True)
        raise ValueError(
            f"{source}, a lake's backup, does not fit a DuckDB file "
            f"({error_line(error)}): restore it into a lake (--results)"
        ) from None
    aside = _set_aside(db)
    fresh.rename(db)
    return aside, scan(db, artifacts)


def _fitting(
    theirs: dict[str, list[str]], ours: dict[str, list[str]], source: Path, target: Path | Lake
) -> dict[str, list[str]]:
    """The backup's tables (``theirs``), or ValueError in one line when one of them, or one of
    their columns, is not in the database restored into (a newer Ringside's backup)."""
    extra = [table for table in sorted(theirs) if table not in ours]
    extra += [
        f"{table}.{column}"
        for table, columns in sorted(theirs.items())
        if table in ours
        for column in columns
        if column not in ours[table]
    ]
    if extra:
        raise ValueError(
            f"{source} has tables or columns {target} does not ({', '.join(extra[:5])}): a newer "
            "Ringside's backup? nothing changed"
        )
    return theirs
