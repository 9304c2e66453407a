"""Prefect tasks of the ingest stage: thin wrappers that add storage and caching to the work."""

from __future__ import annotations

from pathlib import Path

from prefect import task
from prefect.cache_policies import NO_CACHE

from storage.paths import data_paths
from tasks.ingest.config import AdversaryDeclaration, IngestConfig
from tasks.ingest.probe import VideoFile, identify
from tasks.ingest.stage import STAGE, ingest_code, ingest_upstream, ingest_video
from tasks.runner import StageCall


@task(name="identify-video", cache_policy=NO_CACHE)
def identify_task(path: str) -> VideoFile:
    # Never cached: the bytes behind a path can change, and the hash is what says so.
    return identify(Path(path))


def ingest_call(
    data_root: str,
    video: VideoFile,
    declaration: AdversaryDeclaration,
    config: IngestConfig,
    key: str,
) -> StageCall:
    paths = data_paths(data_root)
    return StageCall(
        run_name=f"ingest-{video.video_id:.12}",
        stage=STAGE,
        video_id=video.video_id,
        key=key,
        config=config,
        code=ingest_code(),
        upstream=ingest_upstream(video.video_id, declaration),
        compute=lambda: ingest_video(
            video, declaration, config, key=key, artifacts=paths.artifacts
        ),
    )
