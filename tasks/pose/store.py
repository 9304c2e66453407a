"""The pose stage's SQL: the analyst's choice of adversary track, and the fighters' keypoints the
lift starts from."""

from __future__ import annotations

from dataclasses import dataclass

import duckdb
import numpy as np

from storage.db import utcnow
from tasks.errors import BadInput


@dataclass(frozen=True)
class TrackRow:
    """A ``pose_tracks`` row: one track of a person and the role it was given."""

    track: int
    shot: int
    role: str  # 'adversary', 'opponent' or 'other'
    first_frame: int
    last_frame: int
    frames_observed: int


@dataclass(frozen=True)
class MediaRow:
    """A ``pose_media`` row: the overlay (``frame``: the video frame it starts at) or a still."""

    kind: str  # 'overlay' or 'still'
    frame: int
    artifact: str


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


def fighter_keypoints(
    con: duckdb.DuckDBPyConnection, video_id: str, pose_key: str
) -> dict[str, np.ndarray]:
    """Both fighters' refined keypoints of pose output ``pose_key``, as columns (role, frame,
    x, y, confidence, world, track), by role then frame."""
    return con.execute(
        "SELECT role, frame, x, y, confidence, world, track FROM pose_keypoints "
        "WHERE key = ? AND video_id = ? ORDER BY role, frame",
        [pose_key, video_id],
    ).fetchnumpy()


def pose_media(con: duckdb.DuckDBPyConnection, key: str, video_id: str) -> list[tuple]:
    """(kind, frame, artifact) of pose output ``key``'s review media: its overlay and stills."""
    return con.execute(
        "SELECT kind, frame, artifact FROM pose_media WHERE key = ? AND video_id = ? "
        "ORDER BY kind, frame",
        [key, video_id],
    ).fetchall()


def pose_tracks(con: duckdb.DuckDBPyConnection, key: str, video_id: str) -> list[tuple]:
    """(track, shot, role, first_frame, last_frame, frames_observed) of every track of pose
    output ``key``, by first frame."""
    return con.execute(
        "SELECT track, shot, role, first_frame, last_frame, frames_observed FROM pose_tracks "
        "WHERE key = ? AND video_id = ? ORDER BY first_frame, track",
        [key, video_id],
    ).fetchall()


def track_handovers(con: duckdb.DuckDBPyConnection, key: str, video_id: str) -> list[tuple]:
    """(frame, role, from_track, to_track) where a fighter's keypoints move to another track."""
    return con.execute(
        """
        WITH seen AS (
            SELECT frame, role, track,
                   lag(track) OVER (PARTITION BY role ORDER BY frame) AS from_track
            FROM pose_keypoints WHERE key = ? AND video_id = ? AND track >= 0
        )
        SELECT frame, role, from_track, track AS to_track FROM seen
        WHERE from_track IS NOT NULL AND from_track <> track ORDER BY frame, role
        """,
        [key, video_id],
    ).fetchall()


def joint_confidence(con: duckdb.DuckDBPyConnection, key: str, video_id: str) -> list[tuple]:
    """(role, joint index, mean estimator confidence over the tracked frames) of each fighter's
    joints in pose output ``key``."""
    return con.execute(
        """
        SELECT role, joint - 1 AS joint, avg(raw_confidence[joint]) AS confidence
        FROM pose_keypoints, range(1, 34) AS joints(joint)
        WHERE key = ? AND video_id = ? AND track >= 0 AND isfinite(raw_confidence[joint])
        GROUP BY ALL ORDER BY role, joint
        """,
        [key, video_id],
    ).fetchall()
