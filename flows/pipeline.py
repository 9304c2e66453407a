"""``video_to_opponent``: every stage, in order: the per-video stages for each video, then the
adversary's dataset assembled, a MAAIP run trained on it and that run evaluated, its adversary
exported as an opponent folder."""

from __future__ import annotations

import os

from prefect import flow
from prefect.task_runners import ThreadPoolTaskRunner

from flows.config import PIPELINE_STAGES, from_tables
from flows.dataset import assemble_flow, dataset_flow
from flows.evaluate import evaluate_flow
from flows.ingest import ingest_flow
from flows.lift import lift_flow
from flows.pose import pose_flow
from flows.runs import StageSummary
from flows.train import train_flow
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
    pose = pose_flow.with_options(task_runner=chunk_runner(from_tables(config or {}).pose.workers))
    forced = set(rerun or [])
    unknown = forced - set(PIPELINE_STAGES)
    if unknown:
        raise ValueError(
            f"cannot rerun unknown stages {sorted(unknown)}; known: {list(PIPELINE_STAGES)}"
        )
    summaries: list[StageSummary] = []
    failures: list[str] = []
    for video in videos:
        try:
            ingested = ingest_flow(
                data_root,
                video,
                adversary,
                adversary_colour,
                notes,
                config,
                force="ingest" in forced,
            )
        except BadInput as error:
            failures.append(str(error))
            continue
        summaries.append(ingested)
        if "pose" not in stages:
            continue
        try:
            posed = pose(data_root, ingested.video_id, ingested.key, config, force="pose" in forced)
            summaries.append(posed)
            if "lift" not in stages:
                continue
            lifted = lift_flow(
                data_root,
                ingested.video_id,
                ingested.key,
                posed.key,
                config,
                force="lift" in forced,
            )
            summaries.append(lifted)
            if "dataset" in stages:
                summaries.append(
                    dataset_flow(
                        data_root,
                        ingested.video_id,
                        ingested.key,
                        lifted.key,
                        config,
                        force="dataset" in forced,
                    )
                )
        except BadInput as error:
            failures.append(str(error))
    if any(s.stage == "dataset" for s in summaries):
        # Every video of this adversary with a current dataset output, not only this run's.
        try:
            assembled = assemble_flow(data_root, adversary, config, "dataset" in forced)
            summaries.append(assembled)
            if "train" in stages:
                trained = train_flow(data_root, assembled.key, config, "train" in forced)
                summaries.append(trained)
                if "evaluate" in stages:
                    summaries.append(
                        evaluate_flow(data_root, trained.key, config, "evaluate" in forced)
                    )
        except BadInput as error:
            failures.append(str(error))
    if failures:
        raise PipelineFailed(failures, summaries)
    return summaries
