"""One computation per stage output at a time, across threads, processes and workers.

Before computing an output a run takes an exclusive lock (``flock``) on a file named for the
output in ``DATA/claims``; a second run of the same output waits for that lock, then asks the
database again and reuses what the first committed. The kernel releases the lock of a process
that ends however it ends, SIGKILL included, so a killed run's claim passes on at once, with no
process id to trust or reuse. Claiming writes nothing to the database: a refused input leaves
its file byte for byte as it was. The lock reaches as far as the file system's locks do, as the
DuckDB file's own lock: every process of this machine, and of every machine on an NFS share with
working locks.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from storage.records import this_worker


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
