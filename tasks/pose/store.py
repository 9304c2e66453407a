"""The pose stage's own rows besides its outputs: the analyst's choice of adversary track."""

from __future__ import annotations

import duckdb

from storage.db import utcnow
from tasks.errors import BadInput


def newest_pick(con: duckdb.DuckDBPyConnection, video_id: str) -> int | None:
    """The analyst's newest choice of adversary track for ``video_id`` (`ringside pick`, the
    dashboard's Pose page), if any: an input of the pose stage."""
    row = con.execute(
        "SELECT track FROM pose_picks WHERE video_id = ? ORDER BY picked_at DESC LIMIT 1",
        [video_id],
    ).fetchone()
    return None if row is None else int(row[0])


def record_pick(con: duckdb.DuckDBPyConnection, video_id: str, track: int) -> None:
    """Store the analyst's choice of ``track`` as the adversary of ``video_id`` (read back by
    `newest_pick`); BadInput when the video has no such track."""
    tracks = sorted(
        row[0]
        for row in con.execute(
            "SELECT DISTINCT track FROM pose_tracks WHERE video_id = ?", [video_id]
        ).fetchall()
    )
    if track not in tracks:
        raise BadInput(
            f"--track {track}", f"video {video_id[:12]} has no such track; tracks: {tracks}"
        )
    con.execute("INSERT INTO pose_picks VALUES (?, ?, ?)", [video_id, track, utcnow()])
