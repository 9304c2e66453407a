"""The Prefect task decorator every stage's output task uses."""

from __future__ import annotations

from prefect import task
from prefect.cache_policies import NO_CACHE


def stage_task(name: str, run_name: str | None = None):
    """``@task`` without Prefect's cache: whether a stage's output exists is asked of the
    database, the source of truth, once, before the task is called (`flows.runs.reuse_or_run`).
    A Prefect cache here was a second and a third check of the same thing (its hit was thrown
    away when the database had lost the output); only the pose chunks keep one, where it pays.
    """
    return task(name=name, cache_policy=NO_CACHE, task_run_name=run_name)
