"""The ingest stage's plan: a video file identified by its bytes, registered, probed."""

from __future__ import annotations

from pathlib import Path

from prefect import task
from prefect.cache_policies import NO_CACHE

from storage.claims import output_claimed
from storage.db import connect
from storage.paths import DataPaths
from storage.records import register_video
from tasks.ingest.config import IngestConfig, declare
from tasks.ingest.probe import VideoFile, identify
from tasks.ingest.stage import ingest_spec, ingest_video
from tasks.runner import StagePlan
from tasks.stage_inputs import Declared


@task(name="identify-video", cache_policy=NO_CACHE)
def identify_task(path: str) -> VideoFile:
    # Never cached: the bytes behind a path can change, and the hash is what says so.
    return identify(Path(path))


def ingest_plan(paths: DataPaths, config: IngestConfig, video: str, inputs: Declared) -> StagePlan:
    """Probe ``video`` (its shots, chunks, timing) and register it, under the adversary the
    analyst declared (``inputs``: adversary, adversary_colour, notes)."""
    declaration = declare(inputs.adversary, inputs.adversary_colour, inputs.notes)
    file = identify_task(video)
    spec = ingest_spec(config, file.video_id, declaration)

    def register() -> None:
        # Whether computed or reused: the same bytes may come from a new path. Under a claim:
        # a lake's tables have no key to refuse a second row, and two machines may register
        # one video at the same moment.
        claim = output_claimed(paths, "register", file.video_id, file.path)
        with claim, connect(paths.db) as con:
            register_video(con, file.video_id, file.size_bytes, file.path)

    return StagePlan(
        spec,
        file.path,
        compute=lambda: ingest_video(file, declaration, config),
        after=register,
        noted=False,
    )
