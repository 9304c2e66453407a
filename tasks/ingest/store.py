"""The ingest stage's reads of the database: a committed ingest output, for the stages that start
from it; the videos registered and ingested, for the CLI and the folder watcher."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import duckdb

from tasks.errors import BadInput


@dataclass(frozen=True)
class ProbeRow:
    """An ``ingest_probes`` row: what the video is (`tasks.ingest.probe.Probe`)."""

    path: str
    fps: float
    frames: int
    frames_declared: int
    width: int
    height: int
    codec: str
    duration_s: float
    source_frames: list[int] | None


@dataclass(frozen=True)
class AdversaryRow:
    """An ``ingest_adversaries`` row: who the analyst says the adversary is."""

    name: str
    colour: str | None
    notes: str | None


@dataclass(frozen=True)
class ShotRow:
    """An ``ingest_shots`` row: a shot between cuts, frames [start_frame, end_frame)."""

    shot: int
    start_frame: int
    end_frame: int
    cut_distance: float | None
    thumbnail: str  # artifact name of a PNG of the shot's first frame


@dataclass(frozen=True)
class ChunkRow:
    """An ``ingest_chunks`` row: frames [start_frame, end_frame) later stages process together."""

    chunk: int
    shot: int
    start_frame: int
    end_frame: int


@dataclass(frozen=True)
class IngestOutput:
    """What later stages need to know about an ingested video."""

    video_id: str
    key: str
    path: str
    fps: float
    frames: int
    width: int
    height: int
    adversary: str
    colour: str | None
    chunks: tuple[tuple[int, int, int, int], ...]  # (chunk, shot, start, end)
    shots: tuple[tuple[int, int, int], ...]  # (shot, start, end)
    # Variable frame rate: the decoded frame shown at each frame of the constant grid.
    source_frames: tuple[int, ...] | None = None

    @property
    def shot_frames(self) -> dict[int, int]:
        """Shot -> frames in it."""
        return {shot: end - start for shot, start, end in self.shots}


def load_ingest(con: duckdb.DuckDBPyConnection, video_id: str, key: str) -> IngestOutput:
    """The ingest output ``key`` of ``video_id``; KeyError if it was never committed."""
    probe = con.execute(
        """
        SELECT p.path, p.fps, p.frames, p.width, p.height, a.name, a.colour, p.source_frames
        FROM ingest_probes p JOIN ingest_adversaries a USING (key, video_id)
        WHERE p.key = ? AND p.video_id = ?
        """,
        [key, video_id],
    ).fetchone()
    if probe is None:
        raise KeyError(f"no ingest output {key} for video {video_id}")
    chunks = con.execute(
        "SELECT chunk, shot, start_frame, end_frame FROM ingest_chunks "
        "WHERE key = ? AND video_id = ? ORDER BY chunk",
        [key, video_id],
    ).fetchall()
    shots = con.execute(
        "SELECT shot, start_frame, end_frame FROM ingest_shots "
        "WHERE key = ? AND video_id = ? ORDER BY shot",
        [key, video_id],
    ).fetchall()
    path, fps, frames, width, height, name, colour, source = probe
    return IngestOutput(
        video_id,
        key,
        path,
        fps,
        frames,
        width,
        height,
        name,
        colour,
        tuple(chunks),
        tuple(shots),
        None if source is None else tuple(source),
    )


@dataclass(frozen=True)
class IngestedVideo:
    """An ingested video as its newest ingest output declared it: what reruns it."""

    video_id: str
    path: str
    adversary: str
    colour: str | None
    notes: str | None


def ingested_video(con: duckdb.DuckDBPyConnection, video: str) -> IngestedVideo:
    """The one ingested video whose id starts with ``video``; BadInput if none or several."""
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


def registered_videos(con: duckdb.DuckDBPyConnection) -> Registered:
    """The ``videos`` and ``video_files`` tables."""
    # Oldest first, so a path registered again with new bytes maps to its newest size.
    files = con.execute(
        "SELECT f.path, v.size_bytes FROM video_files f JOIN videos v USING (video_id) "
        "ORDER BY f.registered_at"
    ).fetchall()
    ids = con.execute("SELECT video_id FROM videos").fetchall()
    return Registered(dict(files), frozenset(row[0] for row in ids))


def video_list(con: duckdb.DuckDBPyConnection) -> list[dict[str, Any]]:
    """Every registered video, oldest first: its id, the newest path it was registered from and
    the adversary its newest ingest output names (None before ingest has finished)."""
    rows = con.execute(
        """
        WITH files AS (
            SELECT video_id, path FROM video_files
            QUALIFY row_number() OVER (PARTITION BY video_id ORDER BY registered_at DESC) = 1
        ), adversaries AS (
            SELECT a.video_id, a.name FROM ingest_adversaries a
            JOIN stage_outputs o ON o.stage = 'ingest' AND o.key = a.key AND o.video_id = a.video_id
            QUALIFY row_number() OVER (PARTITION BY a.video_id ORDER BY o.created_at DESC) = 1
        )
        SELECT v.video_id, f.path, a.name
        FROM videos v LEFT JOIN files f USING (video_id) LEFT JOIN adversaries a USING (video_id)
        ORDER BY v.registered_at, v.video_id
        """
    ).fetchall()
    return [dict(zip(("video_id", "path", "adversary"), row, strict=True)) for row in rows]


def shot_starts(con: duckdb.DuckDBPyConnection, key: str, video_id: str) -> list[int]:
    """The frames where a new shot starts (after the first) in ingest output ``key``."""
    return [
        row[0]
        for row in con.execute(
            "SELECT start_frame FROM ingest_shots WHERE key = ? AND video_id = ? AND shot > 0 "
            "ORDER BY shot",
            [key, video_id],
        ).fetchall()
    ]
