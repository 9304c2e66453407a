"""File helpers shared by the artifact store, the assets and ingest."""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

from tqdm import tqdm

HASH_BLOCK = 4 << 20


# How the temporary files of `write_atomic` are named: TEMPORARY, the writer's pid, a dash.
TEMPORARY = ".tmp-"


# How a stage's scratch folders in the system's temporary directory are named: SCRATCH, what
# they hold, the pid of the process that made them, a dash (`scratch_dir`).
SCRATCH = "ringside-"


def scratch_dir(kind: str) -> tempfile.TemporaryDirectory:
    """A scratch folder removed when its ``with`` block ends; its name carries this process's
    pid, so a later command can remove the folder of a process killed inside the block."""
    return tempfile.TemporaryDirectory(prefix=f"{SCRATCH}{kind}-{os.getpid()}-")


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` beside ``path`` and rename it into place: a killed process leaves either
    the old file or the new one, never a partial file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    # The writer's pid in the name tells a later reader whether the file is still being written.
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f"{TEMPORARY}{os.getpid()}-")
    try:
        with os.fdopen(fd, "wb") as out:
            out.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def sha256_file(path: Path, *, progress: str | None = None) -> str:
    """SHA-256 of the file's bytes, read in blocks; ``progress`` labels a progress bar (shown on
    an interactive terminal only)."""
    h = hashlib.sha256()
    with (
        path.open("rb") as f,
        tqdm(
            total=path.stat().st_size,
            unit="B",
            unit_scale=True,
            desc=progress,
            disable=None if progress else True,
        ) as bar,
    ):
        while block := f.read(HASH_BLOCK):
            h.update(block)
            bar.update(len(block))
    return h.hexdigest()
