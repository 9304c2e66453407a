"""One computation per stage output at a time, across threads, processes and workers.

Before computing an output a run claims its key in the database; DuckDB lets one process write
at a time, so of two runs only one can take a free claim. The other waits until the claim is
released (the output committed, or the computation failed) and asks the database again. A
claim whose process is gone (killed) is taken over. A claim of a process on another host is
trusted as long as it stands (this host cannot see that process): `ringside check --repair`
clears claims.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import duckdb

from storage.db import connect, transaction, utcnow
from storage.records import this_worker, worker_alive

POLL_S = 0.5


def _owner() -> str:
    """This thread as ``host:pid/thread``: two threads of one process (a pipeline's videos in
    parallel) claim apart."""
    return f"{this_worker()}/{threading.get_ident()}"


def _alive(owner: str) -> bool:
    return worker_alive(owner.partition("/")[0])


def take_claim(con: duckdb.DuckDBPyConnection, stage: str, video_id: str, key: str) -> str | None:
    """Claim the output for this thread: None when taken (free, ours already, or its owner
    gone), else the live owner that holds it."""
    me = _owner()
    with transaction(con):
        row = con.execute(
            "SELECT worker FROM stage_claims WHERE stage = ? AND video_id = ? AND key = ?",
            [stage, video_id, key],
        ).fetchone()
        if row is not None and row[0] != me and _alive(row[0]):
            return row[0]
        con.execute(
            "INSERT OR REPLACE INTO stage_claims VALUES (?, ?, ?, ?, ?)",
            [stage, video_id, key, me, utcnow()],
        )
    return None


def release_claim(con: duckdb.DuckDBPyConnection, stage: str, video_id: str, key: str) -> None:
    """Give this thread's claim up (another's is left alone)."""
    con.execute(
        "DELETE FROM stage_claims WHERE stage = ? AND video_id = ? AND key = ? AND worker = ?",
        [stage, video_id, key, _owner()],
    )


@contextmanager
def claimed(
    db: Path,
    stage: str,
    video_id: str,
    key: str,
    waiting: Callable[[str], None] = lambda _owner: None,
) -> Iterator[bool]:
    """Hold the claim on one output while the block runs; yields whether another run held it
    first (it may have committed the output meanwhile: ask the database again). ``waiting``
    is told the holder once, when this one has to wait."""
    waited = False
    while True:
        with connect(db) as con:
            holder = take_claim(con, stage, video_id, key)
        if holder is None:
            break
        if not waited:
            waiting(holder)
            waited = True
        time.sleep(POLL_S)
    try:
        yield waited
    finally:
        with connect(db) as con:
            release_claim(con, stage, video_id, key)
