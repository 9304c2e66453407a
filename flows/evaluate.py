"""The evaluate stage as a flow: one finished training run judged, its adversary exported."""

from __future__ import annotations

import math

from prefect import flow
from prefect.artifacts import create_table_artifact

from flows.config import from_tables
from flows.runs import StageSummary, reuse_or_run
from storage.db import connect
from storage.paths import data_paths
from tasks.dataset.store import dataset_info
from tasks.errors import BadInput
from tasks.evaluate.store import STAGE, compared_runs, evaluation_tables, resolve_run
from tasks.evaluate.task import evaluate_call, evaluate_key
from tasks.runner import StageCall


def _cell(value):
    """A table cell Prefect can store as JSON: NaN as None, booleans as text."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float) and math.isnan(value):
        return None
    return value


def publish_tables(data_root: str, key: str, run_key: str) -> None:
    """The evaluation's tables as Prefect table artifacts, one per non-empty table."""
    with connect(data_paths(data_root).db, read_only=True) as con:
        tables = evaluation_tables(con, key, run_key)
    for name, rows in tables.items():
        if rows:
            create_table_artifact(
                key=f"evaluate-{name}-{run_key[:12]}",
                table=[{k: _cell(v) for k, v in r.items()} for r in rows],
                description=f"evaluate {name} of training run {run_key[:12]} (key {key})",
            )


@flow(name="evaluate", flow_run_name="evaluate-{run_key:.12}")
def evaluate_flow(
    data_root: str, run_key: str, config: dict | None = None, force: bool = False
) -> StageSummary:
    """Evaluate finished training run ``run_key`` (a prefix will do; `ringside metrics --stage
    train` lists them). The settings and the run are checked before anything is computed."""
    settings = from_tables(config or {}).evaluate
    db = data_paths(data_root).db
    if not db.exists():
        raise BadInput(str(db), "no database yet: process some footage and train first")
    with connect(db) as con:  # writable: brings an older database's schema up to date
        info = resolve_run(con, run_key)
        compared = tuple(other.run_key for other in compared_runs(con, info))
        adversary = dataset_info(con, info.dataset_key).adversary
    key = evaluate_key(settings, info.run_key, compared)

    def call() -> StageCall:
        return evaluate_call(data_root, info.run_key, compared, settings, key)

    result, state = reuse_or_run(
        data_root, stage=STAGE, video_id=info.run_key, key=key, force=force, call=call
    )
    publish_tables(data_root, key, info.run_key)
    return StageSummary(info.run_key, adversary, STAGE, key, state, result.seconds, result.notes)
