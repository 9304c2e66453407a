"""One computation per stage output at a time, across threads, processes and workers.

Before computing an output a run takes an exclusive lock (``flock``) on a file named for the
output in ``DATA/claims``; a second run of the same output waits for that lock, then asks the
database again and reuses what the first committed. The kernel releases the lock of a process
that ends however it ends, SIGKILL included, so a killed run's claim passes on at once, with no
process id to trust or reuse. Claiming writes nothing to the database: a refused input leaves
its file byte for byte as it was. The lock reaches as far as the file system's locks do, as the
DuckDB file's own lock: every process of this machine, and of every machine on an NFS share with
working locks.

With the results in a lake (`storage.paths.Lake`) the machines share no kernel, so the claim is
a PostgreSQL advisory lock in the lake's catalog database instead (`lake_claimed`), held by a
connection of the claiming process: PostgreSQL lets go of it when that connection ends, the
process killed included (its socket closes with it), so a dead owner's claim passes on too.
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import hashlib
import os
import shlex
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import asyncpg

from storage.db import LOCK_WAIT_S, CatalogUnreachable
from storage.paths import DataPaths, Lake
from storage.records import this_worker

# How often a waiting claimant asks PostgreSQL again (a try, not a blocking wait: a blocked
# call would hold the process past a signal).
LAKE_POLL_S = 0.2


def output_claimed(
    paths: DataPaths,
    stage: str,
    video_id: str,
    key: str,
    waiting: Callable[[str], None] = lambda _holder: None,
) -> contextlib.AbstractContextManager[bool]:
    """The claim on one output, as the results' backend keeps it: a lock file of the data
    directory, or the lake's advisory lock."""
    if paths.lake is not None:
        return lake_claimed(paths.lake, stage, video_id, key, waiting)
    return claimed(paths.claims, stage, video_id, key, waiting)


def lock_keys(stage: str, video_id: str, key: str) -> tuple[int, int]:
    """The two 31-bit keys of an output's advisory lock (non-negative, so `pg_locks` shows
    them as they are)."""
    digest = hashlib.sha256(f"{stage}\0{video_id}\0{key}".encode()).digest()
    return (
        int.from_bytes(digest[:4], "big") & 0x7FFFFFFF,
        int.from_bytes(digest[4:8], "big") & 0x7FFFFFFF,
    )


def libpq_settings(catalog: str) -> dict[str, str]:
    """libpq's ``key=value`` connection string as asyncpg's keyword arguments."""
    names = {"dbname": "database", "host": "host", "port": "port", "user": "user",
             "password": "password"}  # fmt: skip
    settings = {}
    for word in shlex.split(catalog):
        name, _, value = word.partition("=")
        if name not in names:
            raise ValueError(f"{catalog!r}: {name!r} is not one of {', '.join(names)}")
        settings[names[name]] = value
    return settings


class _Session:
    """One PostgreSQL connection, on an event loop of its own thread: callable from any thread
    of ours, whether or not an event loop runs there (Prefect's)."""

    def __init__(self, catalog: str) -> None:
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True)
        self._thread.start()
        try:
            settings = libpq_settings(catalog)
            self._con = self.run(
                asyncpg.connect(**settings, server_settings={"application_name": this_worker()})
            )
        except BaseException:
            self._stop()
            raise

    def run(self, coroutine):
        return asyncio.run_coroutine_threadsafe(coroutine, self._loop).result()

    def fetchval(self, sql: str, *args):
        """The first value of ``sql``'s first row."""
        return self.run(self._con.fetchval(sql, *args))

    def close(self) -> None:
        try:
            self.run(self._con.close(timeout=5))
        except (OSError, asyncpg.PostgresError, asyncpg.InterfaceError, TimeoutError):
            # PostgreSQL went away meanwhile (a restart) and the lock with it: nothing is left
            # to let go of, and the computation the claim covered is not to fail for it.
            self._loop.call_soon_threadsafe(self._con.terminate)
        finally:
            self._stop()

    def _stop(self) -> None:
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join()
        self._loop.close()


def _session(lake: Lake, wait_s: float = LOCK_WAIT_S) -> _Session:
    """A session on the lake's catalog database; PostgreSQL not answering (a restart) is waited
    for up to ``wait_s``, as `storage.db.connect` waits, then raised in one line."""
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return _Session(lake.catalog)
        except (OSError, asyncpg.CannotConnectNowError) as error:
            if time.monotonic() > deadline:
                raise CatalogUnreachable(
                    f"{lake}: PostgreSQL did not answer for {wait_s:.0f} s ({error})"
                ) from error
            time.sleep(1.0)


_HOLDER = (
    "SELECT a.application_name FROM pg_locks l JOIN pg_stat_activity a ON a.pid = l.pid "
    "WHERE l.locktype = 'advisory' AND l.granted AND l.classid = $1::bigint::oid "
    "AND l.objid = $2::bigint::oid AND l.objsubid = 2"
)


@contextmanager
def lake_claimed(
    lake: Lake,
    stage: str,
    video_id: str,
    key: str,
    waiting: Callable[[str], None] = lambda _holder: None,
) -> Iterator[bool]:
    """`claimed` for a lake: the output's advisory lock in the catalog's database."""
    first, second = lock_keys(stage, video_id, key)
    session = _session(lake)
    try:
        waited = False
        while not session.fetchval("SELECT pg_try_advisory_lock($1, $2)", first, second):
            if not waited:
                holder = session.fetchval(_HOLDER, first, second)
                waiting(holder or "another run")
                waited = True
            time.sleep(LAKE_POLL_S)
        yield waited
    finally:
        # Closing the connection lets go of the lock (an explicit unlock would be one more
        # round trip that a lost connection could not make anyway).
        session.close()


def claim_file(folder: Path, stage: str, video_id: str, key: str) -> Path:
    """The lock file of one output (subjects may be paths: the name is a hash of them)."""
    digest = hashlib.sha256(f"{stage}\0{video_id}\0{key}".encode()).hexdigest()[:32]
    return folder / f"{stage}-{digest}.lock"


@contextmanager
def claimed(
    folder: Path,
    stage: str,
    video_id: str,
    key: str,
    waiting: Callable[[str], None] = lambda _holder: None,
) -> Iterator[bool]:
    """Hold the claim on one output while the block runs; yields whether another run held it
    first (it may have committed the output meanwhile: ask the database again). ``waiting``
    is told the holder (``host:pid``) once, when this one has to wait."""
    path = claim_file(folder, stage, video_id, key)
    path.parent.mkdir(parents=True, exist_ok=True)
    waited = False
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if not waited:
                waiting(os.pread(fd, 256, 0).decode(errors="replace") or "another run")
                waited = True
            fcntl.flock(fd, fcntl.LOCK_EX)
        except BaseException:
            os.close(fd)
            raise
        # The holder removes the file as it lets go; a lock on a removed file is no claim.
        try:
            held = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            held = False
        if held:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, this_worker().encode(), 0)
        yield waited
    finally:
        path.unlink(missing_ok=True)
        os.close(fd)
