"""``video_to_opponent``: every stage, in order: the per-video stages for each video, then the
adversary's dataset assembled, a MAAIP run trained on it and that run evaluated, its adversary
exported as an opponent folder."""

from __future__ import annotations

import os

from prefect import flow
from prefect.task_runners import ThreadPoolTaskRunner

from flows.config import flow_inputs
from flows.dataset import assemble_flow
from flows.runs import StageSummary
from flows.stage import run_stage_flow
from tasks import registry
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
    """The stages a run up to ``until`` runs: it and every stage it needs (all when None)."""
    if until is not None and until not in registry.names():
        raise ValueError(f"--until must be one of {', '.join(registry.names())}, got {until!r}")
    return registry.until(until)


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
    paths, settings = flow_inputs(data_root, config)
    stages = stages_until(until)
    chunks = chunk_runner(settings.pose.workers)
    forced = set(rerun or [])
    unknown = forced - set(registry.names())
    if unknown:
        raise ValueError(
            f"cannot rerun unknown stages {sorted(unknown)}; known: {list(registry.names())}"
        )

    def run(stage: str, subject: str, inputs: dict, **options) -> StageSummary:
        summary = run_stage_flow(stage, paths, subject, inputs, config, stage in forced, **options)
        summaries.append(summary)
        return summary

    def keys_of(stage: str, done: dict[str, str]) -> dict[str, str]:
        """The upstream output keys ``stage``'s plan is given."""
        return {name: done[name] for name in registry.stage(stage).upstream}

    summaries: list[StageSummary] = []
    failures: list[str] = []
    declaration = {"adversary": adversary, "adversary_colour": adversary_colour, "notes": notes}
    per_video = [s for s in registry.names(registry.Subject.VIDEO) if s in stages]
    for video in videos:
        try:
            ingested = run("ingest", video, declaration)
        except BadInput as error:
            failures.append(str(error))
            continue
        done = {"ingest": ingested.key}
        try:
            for stage in per_video:
                # The pose stage's chunks run on their own runner (threads or Dask).
                options = {"task_runner": chunks} if stage == "pose" else {}
                done[stage] = run(stage, ingested.video_id, keys_of(stage, done), **options).key
        except BadInput as error:
            failures.append(str(error))
    if any(s.stage == "dataset" for s in summaries):
        # Every video of this adversary with a current dataset output, not only this run's.
        try:
            assembled = assemble_flow(str(paths.root), adversary, config, "dataset" in forced)
            summaries.append(assembled)
            done = {"dataset": assembled.key}
            for stage in registry.names(registry.Subject.DATASET, registry.Subject.RUN):
                if stage in stages:
                    subject = done[registry.stage(stage).upstream[0]]
                    done[stage] = run(stage, subject, {}).key
        except BadInput as error:
            failures.append(str(error))
    if failures:
        raise PipelineFailed(failures, summaries)
    return summaries
