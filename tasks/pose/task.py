"""Prefect tasks of the pose stage: one per chunk (cached each), one to assemble the video."""

from __future__ import annotations

from pathlib import Path

from prefect import task
from prefect.cache_policies import INPUTS, TASK_SOURCE

from storage.artifacts import put_bytes, read_bytes
from storage.db import connect
from storage.paths import data_paths
from tasks.ingest.store import IngestOutput
from tasks.pose.chunk import ChunkTracks
from tasks.pose.config import PoseConfig
from tasks.pose.merge import ChunkSpan
from tasks.pose.stage import (
    STAGE,
    assemble,
    pose_code,
    pose_upstream,
    process_chunk,
)
from tasks.pose.store import newest_pick
from tasks.runner import StageCall


@task(
    name="pose-chunk",
    # The chunk key holds the settings that matter inside a chunk, so the full config is left
    # out: changing how fighters are refined must not recompute every chunk.
    cache_policy=(INPUTS + TASK_SOURCE) - "config",
    persist_result=True,
    task_run_name="pose-chunk-{span.index}",
)
def pose_chunk_task(
    data_root: str,
    video: str,
    span: ChunkSpan,
    fps: float,
    config: PoseConfig,
    models: tuple[str, str],
    chunk_key: str,
) -> str:
    """Track one chunk; its result goes to the artifact store and the task returns its name."""
    paths = data_paths(data_root)
    tracks = process_chunk(Path(video), span, fps, config, (Path(models[0]), Path(models[1])))
    return put_bytes(paths.artifacts, tracks.to_bytes(), ".npz")


def load_chunk(data_root: str, name: str) -> ChunkTracks:
    return ChunkTracks.from_bytes(read_bytes(data_paths(data_root).artifacts, name))


def latest_pick(db: Path, video_id: str) -> int | None:
    """The analyst's newest choice of adversary track for ``video_id``, if any."""
    if not db.exists():
        return None
    with connect(db, read_only=True) as con:
        return newest_pick(con, video_id)


def pose_call(
    data_root: str,
    ingest: IngestOutput,
    spans: list[ChunkSpan],
    chunk_names: list[str],
    config: PoseConfig,
    key: str,
    pick: int | None,
) -> StageCall:
    """Assemble the chunks into the video's pose output and commit it under ``key``."""
    paths = data_paths(data_root)

    def compute():
        return assemble(
            Path(ingest.path),
            spans,
            [load_chunk(data_root, name) for name in chunk_names],
            key=key,
            video_id=ingest.video_id,
            frames=ingest.frames,
            fps=ingest.fps,
            size=(ingest.width, ingest.height),
            shots=ingest.shot_frames,
            colour=ingest.colour,
            pick=pick,
            config=config,
            artifacts=paths.artifacts,
            source_frames=ingest.source_frames,
        )

    return StageCall(
        run_name=f"pose-{ingest.video_id:.12}",
        stage=STAGE,
        video_id=ingest.video_id,
        key=key,
        config=config,
        code=pose_code(),
        upstream=pose_upstream(ingest.key, pick),
        compute=compute,
    )
