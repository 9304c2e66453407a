"""The Prefect task decorator every stage's output task uses."""

from __future__ import annotations

from prefect import task
from prefect.cache_policies import INPUTS, TASK_SOURCE


def stage_task(name: str, run_name: str | None = None):
    """``@task`` cached on its inputs and source, never on ``force``, with persisted results.

    The results are small records (keys and metrics, `tasks.runner.StageResult`); the database
    stays the source of truth.
    """
    return task(
        name=name,
        cache_policy=(INPUTS + TASK_SOURCE) - "force",
        persist_result=True,
        task_run_name=run_name,
    )
