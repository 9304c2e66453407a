"""The pose stage as a flow: chunks tracked concurrently, then assembled for the video."""

from __future__ import annotations

from pathlib import Path

from prefect import flow
from prefect.runtime import flow_run
from prefect.task_runners import ThreadPoolTaskRunner
from tqdm import tqdm

from flows.config import from_tables
from flows.runs import StageSummary, reuse_or_run
from storage.artifacts import artifact_path
from storage.db import connect
from storage.files import sha256_file
from storage.paths import data_paths
from tasks.ingest.store import IngestOutput, load_ingest
from tasks.pose.chunk import STOP
from tasks.pose.config import PoseConfig
from tasks.pose.merge import ChunkSpan
from tasks.pose.stage import STAGE, chunk_key, model_files, plan_spans, pose_key
from tasks.pose.task import latest_pick, pose_call, pose_chunk_task
from tasks.runner import StageCall


def _run_name() -> str:
    return f"pose-{flow_run.parameters['video_id'][:12]}"


@flow(name="pose", flow_run_name=_run_name, task_runner=ThreadPoolTaskRunner(max_workers=1))
def pose_flow(
    data_root: str,
    video_id: str,
    ingest_key: str,
    config: dict | None = None,
    force: bool = False,
) -> StageSummary:
    """Both fighters' tracks and refined keypoints for an ingested video."""
    settings = from_tables(config or {}).pose
    paths = data_paths(data_root)
    with connect(paths.db, read_only=True) as con:
        ingest = load_ingest(con, video_id, ingest_key)
    pick = latest_pick(paths.db, video_id)
    key = pose_key(settings, ingest_key, pick)

    def call() -> StageCall:
        # Chunks keep their own cache: a forced assembly reuses them.
        spans, names = _track_chunks(data_root, ingest, settings)
        return pose_call(data_root, ingest, spans, names, settings, key, pick)

    result, state = reuse_or_run(
        data_root, stage=STAGE, video_id=video_id, key=key, force=force, call=call
    )
    return StageSummary(video_id, ingest.path, STAGE, key, state, result.seconds, result.notes)


def _track_chunks(
    data_root: str, ingest: IngestOutput, settings: PoseConfig
) -> tuple[list[ChunkSpan], list[str]]:
    """Track every chunk, each cached on its own; their spans and artifact names."""
    paths = data_paths(data_root)
    models = model_files(settings, paths.assets)
    hashes = (sha256_file(models[0]), sha256_file(models[1]))
    spans = plan_spans(list(ingest.chunks), settings.overlap_frames, ingest.source_frames)

    def arguments(span: ChunkSpan) -> tuple:
        key = chunk_key(settings, ingest.video_id, span, hashes)
        return data_root, ingest.path, span, ingest.fps, settings, tuple(map(str, models)), key

    STOP.clear()
    futures = [pose_chunk_task.submit(*arguments(span)) for span in spans]
    names = []
    try:
        # Shown on an interactive terminal only; advances as chunks finish.
        with tqdm(
            total=ingest.frames, unit="frame", desc=f"pose {Path(ingest.path).name}", disable=None
        ) as bar:
            for span, future in zip(spans, futures, strict=True):
                name = future.result()
                if not artifact_path(paths.artifacts, name).exists():
                    # Prefect's cache names a chunk file that is gone (deleted, a lost disk):
                    # the store is the truth, so the chunk is tracked again and cached anew.
                    name = pose_chunk_task.with_options(refresh_cache=True)(*arguments(span))
                names.append(name)
                bar.update(span.end - span.start)
    except BaseException:
        # A stop signal (Prefect raises it here, in the main thread) or a failed chunk: the
        # chunks still at work end at their next frame rather than finishing first.
        STOP.set()
        raise
    return spans, names
