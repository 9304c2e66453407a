"""The pose stage's plan: chunks tracked concurrently (a cached Prefect task each), then
assembled into the video's pose output."""

from __future__ import annotations

from pathlib import Path

from prefect import task
from prefect.cache_policies import INPUTS, TASK_SOURCE
from tqdm import tqdm

from storage.artifacts import put_bytes, read_bytes, sound
from storage.db import connect
from storage.files import sha256_file
from storage.paths import DataPaths
from tasks.ingest.store import IngestOutput, load_ingest
from tasks.pose.chunk import STOP, ChunkTracks
from tasks.pose.config import PoseConfig
from tasks.pose.merge import ChunkSpan
from tasks.pose.stage import assemble, chunk_key, model_files, plan_spans, pose_spec, process_chunk
from tasks.pose.store import newest_pick
from tasks.runner import StagePlan
from tasks.stage_inputs import PoseInputs


@task(
    name="pose-chunk",
    # The chunk key holds the settings that matter inside a chunk, so the full config is left
    # out: changing how fighters are refined must not recompute every chunk.
    cache_policy=(INPUTS + TASK_SOURCE) - "config",
    persist_result=True,
    task_run_name="pose-chunk-{span.index}",
)
def pose_chunk_task(
    paths: DataPaths,
    video: str,
    span: ChunkSpan,
    fps: float,
    config: PoseConfig,
    models: tuple[str, str],
    chunk_key: str,
) -> str:
    """Track one chunk; its result goes to the artifact store and the task returns its name."""
    tracks = process_chunk(Path(video), span, fps, config, (Path(models[0]), Path(models[1])))
    return put_bytes(paths.artifacts, tracks.to_bytes(), ".npz")


def pose_plan(paths: DataPaths, config: PoseConfig, video_id: str, inputs: PoseInputs) -> StagePlan:
    """Both fighters' tracks and refined keypoints of ingest output ``inputs.ingest``, with
    the analyst's newest pick of the adversary's track."""
    with connect(paths.db, read_only=True) as con:
        ingest = load_ingest(con, video_id, inputs.ingest)
        pick = newest_pick(con, video_id)
    spec = pose_spec(config, video_id, ingest.key, pick)
    spans = plan_spans(list(ingest.chunks), config.overlap_frames, ingest.source_frames)

    def compute(names: list[str]):
        """The pose output from the chunks' artifacts (``names``, tracked in the flow)."""
        return assemble(
            Path(ingest.path),
            spans,
            [ChunkTracks.from_bytes(read_bytes(paths.artifacts, name)) for name in names],
            frames=ingest.frames,
            fps=ingest.fps,
            size=(ingest.width, ingest.height),
            shots=ingest.shot_frames,
            colour=ingest.colour,
            pick=pick,
            config=config,
            source_frames=ingest.source_frames,
        )

    # Chunks keep their own cache: a forced assembly reuses them.
    return StagePlan(
        spec,
        ingest.path,
        compute,
        before=lambda: (track_chunks(paths, ingest, config, spans),),
    )


def track_chunks(
    paths: DataPaths, ingest: IngestOutput, config: PoseConfig, spans: list[ChunkSpan]
) -> list[str]:
    """Track every chunk, each cached on its own; their artifacts' names."""
    models = model_files(config, paths.assets)
    hashes = (sha256_file(models[0]), sha256_file(models[1]))

    def arguments(span: ChunkSpan) -> tuple:
        key = chunk_key(config, ingest.video_id, span, hashes)
        return paths, ingest.path, span, ingest.fps, config, tuple(map(str, models)), key

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
                if not sound(paths.artifacts, name):
                    # Prefect's cache names a chunk file that is gone or corrupt (deleted, a
                    # lost disk; a corrupt one is quarantined): the store is the truth, so the
                    # chunk is tracked again and cached anew.
                    name = pose_chunk_task.with_options(refresh_cache=True)(*arguments(span))
                names.append(name)
                bar.update(span.end - span.start)
    except BaseException:
        # A stop signal (Prefect raises it here, in the main thread) or a failed chunk: the
        # chunks still at work end at their next frame rather than finishing first.
        STOP.set()
        raise
    return names
