"""The one Prefect task that computes and commits any stage's output."""

from __future__ import annotations

from collections.abc import Callable

from prefect import task
from prefect.cache_policies import NO_CACHE
from prefect.runtime import flow_run

from storage.paths import DataPaths
from tasks.runner import StageOutput, StageResult, StageSpec, run_stage


@task(name="stage", cache_policy=NO_CACHE)
def _stage_task(
    paths: DataPaths, spec: StageSpec, compute: Callable[[], StageOutput], started: float
) -> StageResult:
    return run_stage(paths, spec, compute, str(flow_run.id), started)


def run_stage_task(
    paths: DataPaths,
    spec: StageSpec,
    compute: Callable[[], StageOutput],
    started: float,
) -> StageResult:
    """Compute and commit ``spec``'s output as a Prefect task run named for its stage; its
    seconds count from ``started`` (a `time.perf_counter` reading in this process), so they
    hold what the flow did for the stage before this task (`tasks.runner.run_stage`).

    Without Prefect's cache: whether a stage's output exists is asked of the database, the
    source of truth, once, before this is called (`flows.runs.reuse_or_run`). A Prefect cache
    here was a second and a third check of the same thing (its hit was thrown away when the
    database had lost the output); only the pose chunks keep one, where it pays.
    """
    named = _stage_task.with_options(name=spec.stage, task_run_name=spec.run_name)
    return named(paths, spec, compute, started)
