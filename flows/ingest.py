"""The ingest stage as a flow: one video file in, one registered video and its ingest output."""

from __future__ import annotations

from pathlib import Path

from prefect import flow
from prefect.runtime import flow_run

from flows.config import from_tables
from flows.runs import StageSummary, reuse_or_run
from storage.db import connect
from storage.paths import data_paths
from storage.records import register_video
from tasks.ingest.config import declare
from tasks.ingest.stage import STAGE, ingest_key
from tasks.ingest.task import identify_task, ingest_call
from tasks.runner import StageCall


def _run_name() -> str:
    return f"ingest-{Path(flow_run.parameters['video']).name}"


@flow(name="ingest", flow_run_name=_run_name)
def ingest_flow(
    data_root: str,
    video: str,
    adversary: str,
    adversary_colour: str | None = None,
    notes: str | None = None,
    config: dict | None = None,
    force: bool = False,
) -> StageSummary:
    """Register ``video`` and probe it; ``force`` recomputes even when a cached output exists."""
    settings = from_tables(config or {}).ingest
    declaration = declare(adversary, adversary_colour, notes)
    file = identify_task(video)
    key = ingest_key(settings, file.video_id, declaration)

    def call() -> StageCall:
        return ingest_call(data_root, file, declaration, settings, key)

    result, state = reuse_or_run(
        data_root, stage=STAGE, video_id=file.video_id, key=key, force=force, call=call, noted=False
    )
    # Registered whether computed or reused: the same bytes may come from a new path.
    with connect(data_paths(data_root).db) as con:
        register_video(con, file.video_id, file.size_bytes, file.path)
    return StageSummary(
        file.video_id, file.path, "ingest", key, state, result.seconds, result.notes
    )
