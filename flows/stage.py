"""The one flow that runs any stage for one subject: plan its output, reuse the committed one
or compute it, summarise."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from prefect import flow
from prefect.task_runners import ThreadPoolTaskRunner

from flows.config import flow_inputs
from flows.runs import StageSummary, reuse_or_run
from storage.paths import DataPaths
from tasks import registry


# One task at a time unless the caller says otherwise (the pose stage's chunks: `chunk_runner`).
@flow(name="stage", task_runner=ThreadPoolTaskRunner(max_workers=1))
def stage_flow(
    data_root: str,
    stage: str,
    subject: str,
    inputs: dict[str, Any] | None = None,
    config: dict | None = None,
    force: bool = False,
) -> StageSummary:
    """Stage ``stage``'s output for ``subject`` (a video file for ingest, a video id, a dataset
    key or a training run key) from ``inputs`` (the upstream outputs' keys; ingest's are the
    adversary's declaration); ``force`` recomputes even when a committed output exists."""
    paths, settings = flow_inputs(data_root, config)
    declared = registry.stage(stage)
    # A flow's parameters are JSON: the plan gets its stage's typed inputs.
    plan = declared.planner()(
        paths, getattr(settings, stage), subject, declared.inputs(**(inputs or {}))
    )
    result, state = reuse_or_run(paths, plan, force)
    plan.after()
    return StageSummary(
        plan.spec.subject,
        plan.name,
        plan.spec.stage,
        result.key,
        state,
        result.seconds,
        result.notes,
    )


def run_stage_flow(
    stage: str,
    paths: DataPaths,
    subject: str,
    inputs: Mapping[str, Any] | None = None,
    config: dict | None = None,
    force: bool = False,
    task_runner=None,
) -> StageSummary:
    """`stage_flow` as a flow run named for its stage and subject, as Prefect's UI lists it
    (``ingest-fight.mp4``, ``pose-3f2a…``)."""
    file = registry.stage(stage).subject is registry.Subject.FILE
    label = Path(subject).name if file else subject[:12]
    options: dict[str, Any] = {"name": stage, "flow_run_name": f"{stage}-{label}"}
    if task_runner is not None:
        options["task_runner"] = task_runner
    return stage_flow.with_options(**options)(
        str(paths.root), stage, subject, dict(inputs or {}), config, force
    )
