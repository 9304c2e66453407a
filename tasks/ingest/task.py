"""Prefect tasks of the ingest stage: thin wrappers that add storage and caching to the work."""

from __future__ import annotations

from pathlib import Path

from prefect import task
from prefect.cache_policies import NO_CACHE
from prefect.runtime import flow_run

from storage.paths import data_paths
from tasks.ingest.config import AdversaryDeclaration, IngestConfig
from tasks.ingest.probe import VideoFile, identify
from tasks.ingest.stage import STAGE, ingest_code, ingest_upstream, ingest_video
from tasks.runner import StageResult, run_stage
from tasks.stage_task import stage_task


@task(name="identify-video", cache_policy=NO_CACHE)
def identify_task(path: str) -> VideoFile:
    # Never cached: the bytes behind a path can change, and the hash is what says so.
    return identify(Path(path))


@stage_task("ingest", "ingest-{video.video_id:.12}")
def ingest_task(
    data_root: str,
    video: VideoFile,
    declaration: AdversaryDeclaration,
    config: IngestConfig,
    key: str,
) -> StageResult:
    paths = data_paths(data_root)
    return run_stage(
        db=paths.db,
        stage=STAGE,
        video_id=video.video_id,
        key=key,
        config=config,
        code=ingest_code(),
        upstream=ingest_upstream(video.video_id, declaration),
        run_id=str(flow_run.id),
        compute=lambda: ingest_video(
            video, declaration, config, key=key, artifacts=paths.artifacts
        ),
    )
