"""``watch_folder``: the pipeline on the videos dropped into a folder since it last looked.

``ringside serve --watch DIR`` runs it on a schedule. A file is new when no registered video came
from its path with its size and its bytes are no registered video's (the video id is their
SHA-256). A file still being written (modified within ``settle_s``) waits for the next look.
Files the pipeline cannot ingest, and copies of registered videos, go into a ledger
(``DATA/prefect/watch-ledger.json``) so they are not tried again until they change.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

from prefect import flow, get_run_logger

from flows.config import flow_inputs
from flows.pipeline import PipelineFailed, video_to_opponent
from storage.db import connect
from storage.files import sha256_file, write_atomic
from storage.paths import DataPaths
from tasks.ingest.store import Registered, registered_videos

VIDEO_SUFFIXES = frozenset(
    {".mp4", ".mov", ".m4v", ".mkv", ".avi", ".webm", ".mpg", ".mpeg", ".ts", ".mts", ".wmv"}
)
LEDGER_FILE = "watch-ledger.json"
DEFAULT_SETTLE_S = 10.0


def _registered(paths: DataPaths) -> Registered:
    """The videos registered in the data directory's database; none before the first one."""
    db = paths.db
    if not db.exists():
        return Registered({}, frozenset())
    with connect(db, read_only=True) as con:
        return registered_videos(con)


@dataclass(frozen=True)
class SeenFile:
    path: str  # resolved
    size: int
    mtime_ns: int


def list_videos(folder: Path) -> list[SeenFile]:
    """The video files directly in ``folder`` by suffix, hidden files (partial downloads,
    rsync's temporaries) left out, in name order."""
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: the watched folder does not exist")
    found = []
    for entry in sorted(folder.iterdir()):
        if entry.name.startswith(".") or entry.suffix.lower() not in VIDEO_SUFFIXES:
            continue
        try:
            stat = entry.stat()
        except FileNotFoundError:  # gone since the listing
            continue
        if entry.is_file():
            found.append(SeenFile(str(entry.resolve()), stat.st_size, stat.st_mtime_ns))
    return found


@dataclass(frozen=True)
class Sorted:
    """One look at the folder: which files to consider now and which wait."""

    candidates: list[SeenFile]  # neither registered nor in the ledger, and settled
    waiting: list[SeenFile]  # still being written (or just written)
    known: int  # registered from this path with this size, or unchanged in the ledger


def sort_files(
    files: list[SeenFile],
    *,
    registered_sizes: dict[str, int],
    ledger: dict[str, dict],
    now_ns: int,
    settle_s: float,
) -> Sorted:
    """Split ``files``: known ones (registered from this path with this size, or in the ledger
    unchanged), ones modified within ``settle_s`` of ``now_ns``, and candidates."""
    candidates, waiting, known = [], [], 0
    for f in files:
        noted = ledger.get(f.path)
        if registered_sizes.get(f.path) == f.size or (
            noted is not None and (noted["size"], noted["mtime_ns"]) == (f.size, f.mtime_ns)
        ):
            known += 1
        elif now_ns - f.mtime_ns < settle_s * 1e9:
            waiting.append(f)
        else:
            candidates.append(f)
    return Sorted(candidates, waiting, known)


def ledger_path(paths: DataPaths) -> Path:
    return paths.prefect_home / LEDGER_FILE


def read_ledger(paths: DataPaths) -> dict[str, dict]:
    path = ledger_path(paths)
    return json.loads(path.read_text()) if path.exists() else {}


def failure_of(path: str, failures: list[str]) -> str:
    """The pipeline's one-line failure that names ``path`` (they read "<path>: <problem>")."""
    return next((f for f in failures if f.startswith(f"{path}:")), "not ingested")


class WatchFailed(RuntimeError):
    """Some new videos failed; the run fails so Prefect's UI shows it."""


@flow(name="watch_folder")
def watch_folder(
    data_root: str,
    folder: str,
    adversary: str,
    adversary_colour: str | None = None,
    config: dict | None = None,
    until: str | None = None,
    settle_s: float = DEFAULT_SETTLE_S,
) -> dict[str, list[str]]:
    """Run ``video_to_opponent`` (up to ``until``) on the new videos in ``folder``, declared as
    ``adversary``'s. Returns the paths it processed, those still being written, and the copies
    of registered videos it found."""
    logger = get_run_logger()
    paths, _ = flow_inputs(data_root, config)
    files = list_videos(Path(folder))
    ledger = read_ledger(paths)
    registered = _registered(paths)
    seen = sort_files(
        files,
        registered_sizes=registered.sizes_by_path,
        ledger=ledger,
        now_ns=time.time_ns(),
        settle_s=settle_s,
    )
    noted = dict(ledger)
    new, copies = [], []
    for f in seen.candidates:
        # The same footage under another name is the same video: leave it as registered.
        if sha256_file(Path(f.path)) in registered.video_ids:
            copies.append(f)
        else:
            new.append(f)
    for f in copies:
        ledger[f.path] = {"size": f.size, "mtime_ns": f.mtime_ns, "why": "a registered video"}
    logger.info(
        f"{folder}: {len(files)} videos, {len(new)} new, {len(seen.waiting)} still being "
        f"written, {seen.known + len(copies)} known"
    )
    failures: list[str] = []
    if new:
        try:
            video_to_opponent(
                str(paths.root),
                [f.path for f in new],
                adversary,
                adversary_colour,
                None,
                config,
                until,
            )
        except PipelineFailed as failed:
            failures = failed.failures
        # What ingest could not register would fail the same way next time, until it changes.
        registered_now = _registered(paths).sizes_by_path
        for f in new:
            if f.path not in registered_now:
                why = failure_of(f.path, failures)
                ledger[f.path] = {"size": f.size, "mtime_ns": f.mtime_ns, "why": why}
    if ledger != noted:
        write_atomic(ledger_path(paths), json.dumps(ledger, indent=1).encode())
    if failures:
        raise WatchFailed("; ".join(failures))
    return {
        "processed": [f.path for f in new],
        "waiting": [f.path for f in seen.waiting],
        "copies": [f.path for f in copies],
    }
