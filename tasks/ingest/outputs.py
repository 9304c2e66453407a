"""Reading a committed ingest output back, for the stages that start from it."""

from __future__ import annotations

from dataclasses import dataclass

import duckdb


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
