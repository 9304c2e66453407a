"""A consistent copy of the database (`ringside backup`), and putting one back (`ringside restore`).

The copy is taken while this process holds DuckDB's write lock, after a checkpoint has moved the
write-ahead log into the file, so no writer changes it mid-copy and the copy is one moment of the
database. The artifact store is not copied: its files are named by their hashes and never
change, and `ringside check` says which the restored database names but cannot find.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

from storage.check import Problem, scan
from storage.db import connect, utcnow
from storage.files import sha256_file, write_atomic

DATABASE = "ringside.duckdb"
MANIFEST = "backup.json"


def backup(db: Path, out: Path) -> dict:
    """Copy the database at ``db`` into the folder ``out`` (created; a backup already there is
    replaced only once the new one is complete). Returns the manifest written beside it.

    The copy is read back as `ringside check` reads a database (every row, every block's
    checksum) before it replaces anything: a damaged one raises ValueError and is deleted.
    """
    out.mkdir(parents=True, exist_ok=True)
    partial = out / f".{DATABASE}.partial"
    try:
        with connect(db) as con:  # holds the write lock until the copy is done
            con.execute("CHECKPOINT")
            shutil.copyfile(db, partial)
            tables = {
                table: con.execute(f"SELECT count(*) FROM {table}").fetchone()[0]
                for (table,) in con.execute(
                    "SELECT table_name FROM duckdb_tables() ORDER BY table_name"
                ).fetchall()
            }
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
        partial.rename(out / DATABASE)
    finally:
        partial.unlink(missing_ok=True)  # left only by a failure: the copy was renamed
    write_atomic(out / MANIFEST, json.dumps(manifest, indent=2).encode())
    return manifest


def restore(db: Path, artifacts: Path, backup_dir: Path) -> tuple[Path | None, list[Problem]]:
    """Put the backup in ``backup_dir`` in place of the database at ``db``, whose file (if any)
    is kept beside it as ``<name>.replaced-<time>``. Refuses a backup whose bytes are not the
    ones it was taken with or that does not read back whole. Returns (the kept file, the
    problems `check` finds in the restored database, e.g. artifacts gone since the backup)."""
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
    aside = None
    stamp = time.strftime("%Y%m%d-%H%M%S")
    for current in (db, db.with_name(db.name + ".wal")):
        if current.exists():
            kept = current.with_name(f"{current.name}.replaced-{stamp}")
            current.rename(kept)
            aside = aside or kept
    partial = db.with_name(f".{db.name}.restoring")
    shutil.copyfile(source, partial)
    partial.rename(db)
    return aside, scan(db, artifacts)
