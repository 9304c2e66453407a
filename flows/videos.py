"""What the database knows about registered videos, for the CLI, the scheduler and the dashboard."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from storage.db import connect
from storage.paths import data_paths
from tasks.errors import BadInput


@dataclass(frozen=True)
class IngestedVideo:
    """An ingested video as its newest ingest output declared it: what reruns it."""

    video_id: str
    path: str
    adversary: str
    colour: str | None
    notes: str | None


def ingested_video(data_root: str | Path, video: str) -> IngestedVideo:
    """The one ingested video whose id starts with ``video``."""
    db = data_paths(data_root).db
    if not db.exists():
        raise BadInput(str(db), "no database yet: process a video first")
    with connect(db, read_only=True) as con:
        found = con.execute(
            """
            SELECT p.video_id, p.path, a.name, a.colour, a.notes
            FROM ingest_probes p JOIN ingest_adversaries a USING (key, video_id)
            JOIN stage_outputs o ON o.stage = 'ingest' AND o.key = p.key AND o.video_id = p.video_id
            WHERE p.video_id LIKE ? || '%'
            QUALIFY row_number() OVER (PARTITION BY p.video_id ORDER BY o.created_at DESC) = 1
            """,
            [video],
        ).fetchall()
    if len(found) != 1:
        problem = "matches no ingested video" if not found else "matches several videos"
        raise BadInput(f"--video {video}", f"{problem}; see `ringside status`")
    return IngestedVideo(*found[0])


@dataclass(frozen=True)
class Registered:
    """Every registered video: the paths it was registered from (with its size) and its ids."""

    sizes_by_path: dict[str, int]
    video_ids: frozenset[str]


def registered_videos(data_root: str | Path) -> Registered:
    """The ``videos`` and ``video_files`` tables; empty before the first video."""
    db = data_paths(data_root).db
    if not db.exists():
        return Registered({}, frozenset())
    with connect(db, read_only=True) as con:
        # Oldest first, so a path registered again with new bytes maps to its newest size.
        files = con.execute(
            "SELECT f.path, v.size_bytes FROM video_files f JOIN videos v USING (video_id) "
            "ORDER BY f.registered_at"
        ).fetchall()
        ids = con.execute("SELECT video_id FROM videos").fetchall()
    return Registered(dict(files), frozenset(row[0] for row in ids))
