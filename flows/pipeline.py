"""``video_to_opponent``: every stage, in order: the per-video stages for each video, then the
adversary's dataset assembled, a MAAIP run trained on it and that run evaluated, its adversary
exported as an opponent folder."""

from __future__ import annotations

import os

from prefect import flow
from prefect.task_runners import ThreadPoolTaskRunner

from flows.config import PIPELINE_STAGES, from_tables
from flows.dataset import assemble_flow
from flows.runs import StageSummary
from flows.stage import run_stage_flow
from tasks.errors import BadInput


class PipelineFailed(RuntimeError):
    """Some videos could not be processed; the others were. Carries both."""

    def __init__(self, failures: list[str], summaries: list[StageSummary]):
        super().__init__(failures, summaries)
        self.failures = failures
        self.summaries = summaries

    def __str__(self) -> str:
        return "; ".join(self.failures)


def chunk_runner(workers: int):
    """Where chunk tasks run: on the Dask cluster at ``$RINGSIDE_DASK_ADDRESS`` when set (its
    workers must see the same data directory), else on ``workers`` threads here."""
    address = os.environ.get("RINGSIDE_DASK_ADDRESS")
    if address:
        from prefect_dask import DaskTaskRunner

        check_scheduler(address)
        return DaskTaskRunner(address=address)
    return ThreadPoolTaskRunner(max_workers=workers)


def check_scheduler(address: str, timeout_s: float = 5.0) -> None:
    """Fail in one line when no Dask scheduler answers at ``address``, instead of Dask's 30 s
    wait inside the pose stage and a traceback of 170 lines."""
    from distributed import Client

    try:
        Client(address, timeout=timeout_s, set_as_default=False).close()
    except (OSError, TimeoutError, ValueError) as error:
        raise BadInput(
            f"RINGSIDE_DASK_ADDRESS={address}",
            f"no Dask scheduler answers ({error}); start one "
            "(`dask scheduler`) or unset the variable to track pose on this machine's threads",
        ) from None


def stages_until(until: str | None) -> tuple[str, ...]:
    if until is None:
        return PIPELINE_STAGES
    if until not in PIPELINE_STAGES:
        raise ValueError(f"--until must be one of {', '.join(PIPELINE_STAGES)}, got {until!r}")
    return PIPELINE_STAGES[: PIPELINE_STAGES.index(until) + 1]


@flow(name="video_to_opponent")
def video_to_opponent(
    data_root: str,
    videos: list[str],
    adversary: str,
    adversary_colour: str | None = None,
    notes: str | None = None,
    config: dict | None = None,
    until: str | None = None,
    rerun: list[str] | None = None,
) -> list[StageSummary]:
    """Run the stages up to ``until`` on each video; stages named in ``rerun`` ignore the cache.

    A video that fails does not stop the others; the flow fails at the end, naming each failure.
    """
    stages = stages_until(until)
    chunks = chunk_runner(from_tables(config or {}).pose.workers)
    forced = set(rerun or [])
    unknown = forced - set(PIPELINE_STAGES)
    if unknown:
        raise ValueError(
            f"cannot rerun unknown stages {sorted(unknown)}; known: {list(PIPELINE_STAGES)}"
        )

    def run(stage: str, subject: str, inputs: dict, **options) -> StageSummary:
        summary = run_stage_flow(
            stage, data_root, subject, inputs, config, stage in forced, **options
        )
        summaries.append(summary)
        return summary

    summaries: list[StageSummary] = []
    failures: list[str] = []
    declaration = {"adversary": adversary, "adversary_colour": adversary_colour, "notes": notes}
    for video in videos:
        try:
            ingested = run("ingest", video, declaration)
        except BadInput as error:
            failures.append(str(error))
            continue
        video_id, ingest_key = ingested.video_id, ingested.key
        try:
            if "pose" in stages:
                posed = run("pose", video_id, {"ingest": ingest_key}, task_runner=chunks)
            if "lift" in stages:
                lifted = run("lift", video_id, {"ingest": ingest_key, "pose": posed.key})
            if "dataset" in stages:
                run("dataset", video_id, {"ingest": ingest_key, "lift": lifted.key})
        except BadInput as error:
            failures.append(str(error))
    if any(s.stage == "dataset" for s in summaries):
        # Every video of this adversary with a current dataset output, not only this run's.
        try:
            assembled = assemble_flow(data_root, adversary, config, "dataset" in forced)
            summaries.append(assembled)
            if "train" in stages:
                trained = run("train", assembled.key, {})
                if "evaluate" in stages:
                    run("evaluate", trained.key, {})
        except BadInput as error:
            failures.append(str(error))
    if failures:
        raise PipelineFailed(failures, summaries)
    return summaries
