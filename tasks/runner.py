"""Running one stage for one video: reuse a committed output, or compute and commit a new one."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from storage.db import connect
from storage.records import Columns, OutputRecord, output_metrics, output_run, write_output


@dataclass(frozen=True)
class StageOutput:
    """What a stage computed: rows per table (tuples starting with key, video_id), metrics."""

    rows: Mapping[str, Sequence[tuple] | Columns]
    metrics: Mapping[str, float]
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class StageResult:
    """The small record a stage task returns and Prefect persists: keys, never arrays.

    ``run_id`` is the flow run that computed the output; when it differs from the current run's
    id, the output came from the cache.
    """

    stage: str
    video_id: str
    key: str
    run_id: str
    seconds: float
    metrics: dict[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()


def committed(db: Path, stage: str, video_id: str, key: str) -> StageResult | None:
    """The committed output of ``stage`` for ``video_id`` under ``key``, if there is one."""
    if not db.exists():
        return None
    with connect(db, read_only=True) as con:
        found = output_run(con, stage, video_id, key)
        if found is None:
            return None
        metrics = output_metrics(con, stage, video_id, key)
    run_id, seconds, notes = found
    return StageResult(stage, video_id, key, run_id, seconds, metrics, notes)


@dataclass(frozen=True)
class StageCall:
    """One output a stage is to compute: what its record says (settings, code, upstream keys)
    and how to compute it. Each stage's ``task.py`` builds one; `tasks.stage_task.run_stage_task`
    runs any of them. ``run_name`` names the Prefect task run."""

    run_name: str
    stage: str
    video_id: str
    key: str
    config: Any
    code: str
    upstream: Mapping[str, Any]
    compute: Callable[[], StageOutput]


def run_stage(db: Path, call: StageCall, run_id: str) -> StageResult:
    """Compute ``call``'s output and commit it (whether one is committed already is the
    caller's question: `flows.runs.reuse_or_run`).

    The database is opened only to write, never while the computation runs, so other processes
    can use it meanwhile.
    """
    start = time.perf_counter()
    output = call.compute()
    seconds = time.perf_counter() - start
    record = OutputRecord(
        call.stage, call.video_id, call.key, call.config, call.code, call.upstream, run_id, seconds
    )
    with connect(db) as con:
        write_output(con, record, output.rows, output.metrics, output.notes)
    return StageResult(
        call.stage,
        call.video_id,
        call.key,
        run_id,
        seconds,
        dict(output.metrics),
        tuple(output.notes),
    )
