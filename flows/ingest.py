"""The ingest stage as a flow: one video file in, one registered video and its ingest output."""

from __future__ import annotations

from pathlib import Path

from prefect import flow
from prefect.runtime import flow_run

from flows.config import from_tables
from flows.runs import StageSummary, settle, still_committed
from tasks.ingest.config import declare
from tasks.ingest.stage import ingest_key
from tasks.ingest.task import identify_task, ingest_task


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
    task = ingest_task.with_options(refresh_cache=True) if force else ingest_task
    result = task(data_root, file, declaration, settings, key, force=force)
    if not still_committed(data_root, result):
        result = ingest_task.with_options(refresh_cache=True)(
            data_root, file, declaration, settings, key, force=True
        )
    state = settle(data_root, result)
    return StageSummary(
        file.video_id, file.path, "ingest", key, state, result.seconds, result.notes
    )
