"""What every stage flow does after its task returns: note the run, publish the metrics; and
what a command does about the flow runs a killed one left running."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from prefect.artifacts import create_table_artifact
from prefect.runtime import flow_run

from storage.db import connect
from storage.paths import data_paths
from storage.records import record_run, stale_runs
from tasks.errors import BadInput
from tasks.runner import StageCall, StageResult, committed
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


def settle(data_root: str, result: StageResult) -> str:
    """Record whether ``result`` was computed by this run (``done``) or reused (``cached``), and
    publish its metrics as a Prefect table artifact. Returns the state."""
    run_id = current_run_id()
    state = "done" if result.run_id == run_id else "cached"
    if state == "cached":
        with connect(data_paths(data_root).db) as con:
            record_run(con, run_id, result.video_id, result.stage, result.key, "cached")
    create_table_artifact(
        key=f"{result.stage}-{result.video_id[:12]}",
        table=[{"name": k, "value": v} for k, v in sorted(result.metrics.items())],
        description=f"{result.stage} metrics of video {result.video_id[:12]} (key {result.key})",
    )
    return state


def record_failure(data_root: str, video_id: str, stage: str, key: str, error: BaseException):
    """Note that ``stage`` failed for a registered video, so `ringside status` can say why."""
    with connect(data_paths(data_root).db) as con:
        record_run(con, current_run_id(), video_id, stage, key, "failed", str(error))


def reuse_or_run(
    data_root: str,
    *,
    stage: str,
    video_id: str,
    key: str,
    force: bool,
    call: Callable[[], StageCall],
    noted: bool = True,
) -> tuple[StageResult, str]:
    """The committed output of ``stage`` under ``key`` unless ``force``, else the output of the
    stage's ``call()``, computed and committed by `run_stage_task`, and its state. The database
    is the one cache asked; ``call`` is made only when it has no output (the pose stage tracks
    its chunks then). When ``noted``, the computation is noted as running and a failure on bad
    input as failed, for `ringside status` (ingest is not: its video is not listed before it is
    registered, and an ingest takes seconds).
    """
    db = data_paths(data_root).db
    result = None if force else committed(db, stage, video_id, key)
    if result is None:
        if noted:
            # Seen by `ringside status` and the dashboard while the stage computes.
            with connect(db) as con:
                record_run(con, current_run_id(), video_id, stage, key, "running")
        try:
            result = run_stage_task(db, call())
        except BadInput as error:
            if noted:
                record_failure(data_root, video_id, stage, key, error)
            raise
    return result, settle(data_root, result)


def crash_stale_flow_runs(data_root: str) -> int:
    """Mark as Crashed the flow runs a killed command left RUNNING in Prefect (they stay so for
    ever, in the UI too): those of its stages (`stale_runs`) and the flows above them. Returns
    how many were marked."""
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

    db = data_paths(data_root).db
    if not db.exists():
        return 0
    with connect(db, read_only=True) as con:
        stale = [uuid.UUID(run) for run in stale_runs(con)]
    if not stale:
        return 0
    running = FlowRunFilterState(type=FlowRunFilterStateType(any_=[StateType.RUNNING]))
    marked: set = set()
    with get_client(sync_client=True) as client:
        runs = client.read_flow_runs(
            flow_run_filter=FlowRunFilter(id=FlowRunFilterId(any_=stale), state=running)
        )
        while runs:
            above = []
            for run in runs:
                if run.id in marked:
                    continue
                client.set_flow_run_state(
                    run.id,
                    Crashed(message="its process stopped (killed); seen by a later command"),
                    force=True,
                )
                marked.add(run.id)
                if run.parent_task_run_id is not None:
                    above.append(client.read_task_run(run.parent_task_run_id).flow_run_id)
            runs = [
                parent
                for parent in (client.read_flow_run(i) for i in above if i is not None)
                if parent.state is not None and parent.state.type == StateType.RUNNING
            ]
    return len(marked)
