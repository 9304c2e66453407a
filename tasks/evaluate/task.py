"""The evaluate stage's plan: one finished training run judged, its adversary exported."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from prefect.artifacts import create_table_artifact

from storage.db import connect
from storage.keys import code_version
from storage.paths import DataPaths
from tasks.dataset.store import dataset_info
from tasks.errors import BadInput
from tasks.evaluate.config import EvaluateConfig
from tasks.evaluate.stage import STAGE, evaluate, load_inputs
from tasks.evaluate.store import (
    compared_runs,
    evaluation_tables,
    resolve_run,
)
from tasks.runner import StagePlan, StageSpec
from tasks.stage_inputs import NoInputs
from tasks.train.store import RunInfo, dataset_tracker


def evaluate_code() -> str:
    return code_version(
        "tasks.evaluate",
        "tasks.opponent",  # the controllers its bouts run and the export
        "tasks.dataset",
        "tasks.train",  # its checkpoints' policies and its runs' SQL
        "tasks.media",
        "models.humanoid",
        "models.arena",
        "models.maaip",
        "models.tracking",
    )


def evaluate_spec(
    config: EvaluateConfig, run_key: str, compared: Sequence[str] = (), tracker: str | None = None
) -> StageSpec:
    """The evaluation of ``run_key``; its upstream names the other runs its tables compare it
    with, when there are any (a new damage or heading run on the dataset changes the tables,
    so the key), and the tracker run that replays the held-out footage, when there is one."""
    upstream: dict = {"train": run_key}
    if compared:
        upstream["compared"] = sorted(compared)
    if tracker is not None:
        upstream["tracker"] = tracker
    return StageSpec(STAGE, run_key, config, evaluate_code(), upstream)


def resolve_training_run(db: Path, run_key: str) -> RunInfo:
    """The finished training run ``run_key`` (or a prefix of its key) names; BadInput naming
    what is wrong when there is none, or no database."""
    if not db.exists():
        raise BadInput(str(db), "no database yet: process some footage and train first")
    with connect(db) as con:  # writable: brings an older database's schema up to date
        return resolve_run(con, run_key)


def evaluate_plan(
    paths: DataPaths, config: EvaluateConfig, run_key: str, inputs: NoInputs
) -> StagePlan:
    """Evaluate finished training run ``run_key`` (a prefix will do; `ringside metrics --stage
    train` lists them): bouts, tables, export, video. The run is checked before anything is
    computed; the tables are published as Prefect artifacts whether computed or reused."""
    info = resolve_training_run(paths.db, run_key)
    with connect(paths.db, read_only=True) as con:
        compared = tuple(other.run_key for other in compared_runs(con, info))
        adversary = dataset_info(con, info.dataset_key).adversary
        tracker = dataset_tracker(con, info.dataset_key, config.tracker, "evaluate.tracker")
    tracker_key = None if tracker is None else tracker.run_key
    spec = evaluate_spec(config, info.run_key, compared, tracker_key)
    return StagePlan(
        spec,
        adversary,
        compute=lambda: evaluate(
            load_inputs(paths.db, paths.artifacts, info.run_key, compared, tracker_key),
            config,
        ),
        after=lambda: publish_tables(paths, spec.key, info.run_key),
    )


def _cell(value):
    """A table cell Prefect can store as JSON: NaN as None, booleans as text."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float) and math.isnan(value):
        return None
    return value


def publish_tables(paths: DataPaths, key: str, run_key: str) -> None:
    """The evaluation's tables as Prefect table artifacts, one per non-empty table."""
    with connect(paths.db, read_only=True) as con:
        tables = evaluation_tables(con, key, run_key)
    for name, rows in tables.items():
        if rows:
            create_table_artifact(
                key=f"evaluate-{name}-{run_key[:12]}",
                table=[{k: _cell(v) for k, v in r.items()} for r in rows],
                description=f"evaluate {name} of training run {run_key[:12]} (key {key})",
            )
