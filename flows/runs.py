"""What every stage flow does after its task returns: note the run, publish the metrics; and
what a command does about the flow runs a killed one left running."""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from pathlib import Path

from prefect import get_run_logger
from prefect.artifacts import create_table_artifact
from prefect.runtime import flow_run

from storage.claims import output_claimed
from storage.db import connect
from storage.paths import DataPaths
from storage.records import record_run, stale_runs
from tasks.errors import BadInput
from tasks.runner import StagePlan, StageResult, committed
from tasks.stage_task import run_stage_task


@dataclass(frozen=True)
class StageSummary:
    """One line of a run's summary."""

    video_id: str
    path: str
    stage: str
    key: str
    state: str
    seconds: float
    notes: tuple[str, ...] = ()


def current_run_id() -> str:
    return str(flow_run.id)


def settle(paths: DataPaths, result: StageResult) -> str:
    """Record whether ``result`` was computed by this run (``done``) or reused (``cached``), and
    publish its metrics as a Prefect table artifact. Returns the state."""
    run_id = current_run_id()
    state = "done" if result.run_id == run_id else "cached"
    if state == "cached":
        with connect(paths.db) as con:
            record_run(con, run_id, result.subject, result.stage, result.key, "cached")
    create_table_artifact(
        key=f"{result.stage}-{result.subject[:12]}",
        table=[{"name": k, "value": v} for k, v in sorted(result.metrics.items())],
        description=f"{result.stage} metrics of video {result.subject[:12]} (key {result.key})",
    )
    return state


def reuse_or_run(paths: DataPaths, plan: StagePlan, force: bool) -> tuple[StageResult, str]:
    """The committed output of ``plan`` unless ``force``, else the output its ``compute`` makes,
    committed by `run_stage_task`; and its state. The database is the one cache asked; the
    plan's ``before`` and ``compute`` run only when it has no output, and only in one run at a
    time (`storage.claims`): a second run of the same output waits for the first and reuses
    what it committed (a forced one too, if it had to wait).
    """
    spec = plan.spec
    key = spec.key
    result = None if force else committed(paths.db, spec.stage, spec.subject, key)
    if result is not None:
        return result, settle(paths, result)

    def waiting(holder: str) -> None:
        get_run_logger().info(
            f"{spec.stage} {key[:12]} of {spec.subject[:12]} is being computed by "
            f"{holder}: waiting for it"
        )

    with output_claimed(paths, spec.stage, spec.subject, key, waiting) as waited:
        if waited:
            result = committed(paths.db, spec.stage, spec.subject, key)
        if result is None:
            result = _compute(paths, plan)
    return result, settle(paths, result)


def _compute(paths: DataPaths, plan: StagePlan) -> StageResult:
    # The output's seconds are the stage's whole wall time: its `before` work too (the pose
    # stage's chunks, most of its time), not only `compute`'s.
    started = time.perf_counter()
    spec = plan.spec
    if plan.noted:
        # Seen by `ringside status` and the dashboard while the stage computes.
        with connect(paths.db) as con:
            record_run(con, current_run_id(), spec.subject, spec.stage, spec.key, "running")
    try:
        arguments = plan.before()
        return run_stage_task(paths, spec, functools.partial(plan.compute, *arguments), started)
    except BadInput as error:
        if plan.noted:
            with connect(paths.db) as con:
                record_run(
                    con, current_run_id(), spec.subject, spec.stage, spec.key, "failed", str(error)
                )
        raise


def crash_stale_flow_runs(db: Path) -> int:
    """Mark as Crashed the flow runs a killed command left RUNNING in Prefect (they stay so for
    ever, in the UI too): those of its stages (`stale_runs`) and the flows above them. Returns
    how many were marked."""
    if not db.exists():
        return 0
    with connect(db, read_only=True) as con:
        stale = stale_runs(con)
    return crash_flow_runs(stale, "its process stopped (killed); seen by a later command")


def crash_flow_runs(run_ids: list[str], why: str) -> int:
    """Mark the flow runs ``run_ids`` that are still RUNNING in Prefect, and the RUNNING flows
    above them, as Crashed with the message ``why``; how many were marked."""
    import uuid

    from prefect.client.orchestration import get_client
    from prefect.client.schemas.filters import (
        FlowRunFilter,
        FlowRunFilterId,
        FlowRunFilterState,
        FlowRunFilterStateType,
    )
    from prefect.client.schemas.objects import StateType
    from prefect.states import Crashed

    if not run_ids:
        return 0
    running = FlowRunFilterState(type=FlowRunFilterStateType(any_=[StateType.RUNNING]))
    marked: set = set()
    with get_client(sync_client=True) as client:
        runs = client.read_flow_runs(
            flow_run_filter=FlowRunFilter(
                id=FlowRunFilterId(any_=[uuid.UUID(run) for run in run_ids]), state=running
            )
        )
        while runs:
            above = []
            for run in runs:
                if run.id in marked:
                    continue
                client.set_flow_run_state(run.id, Crashed(message=why), force=True)
                marked.add(run.id)
                if run.parent_task_run_id is not None:
                    above.append(client.read_task_run(run.parent_task_run_id).flow_run_id)
            runs = [
                parent
                for parent in (client.read_flow_run(i) for i in above if i is not None)
                if parent.state is not None and parent.state.type == StateType.RUNNING
            ]
    return len(marked)
