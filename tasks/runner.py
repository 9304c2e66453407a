"""Running one stage for one video: reuse a committed output, or compute and commit a new one."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from storage.artifacts import put_bytes
from storage.db import connect
from storage.keys import stage_key
from storage.paths import DataPaths
from storage.records import Columns, OutputRecord, output_metrics, output_run, write_output


@dataclass(frozen=True)
class StageOutput:
    """What a stage computed: rows per table (records named as the table's columns, or
    `Columns`), metrics, notes, and the files its rows name (artifact name -> bytes,
    `storage.artifacts.artifact_name`), which `run_stage` stores before it commits the rows."""

    rows: Mapping[str, Sequence[Any] | Columns]
    metrics: Mapping[str, float]
    notes: tuple[str, ...] = ()
    files: Mapping[str, bytes] = field(default_factory=dict)


@dataclass(frozen=True)
class StageResult:
    """The small record a stage task returns and Prefect persists: keys, never arrays.

    ``subject`` is what the output is of (`StageSpec`). ``run_id`` is the flow run that
    computed the output; when it differs from the current run's id, the output came from the
    cache.
    """

    stage: str
    subject: str
    key: str
    run_id: str
    seconds: float
    metrics: dict[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()


def committed(db: Path, stage: str, subject: str, key: str) -> StageResult | None:
    """The committed output of ``stage`` for ``subject`` under ``key``, if there is one."""
    if not db.exists():
        return None
    with connect(db, read_only=True) as con:
        found = output_run(con, stage, subject, key)
        if found is None:
            return None
        metrics = output_metrics(con, stage, subject, key)
    run_id, seconds, notes = found
    return StageResult(stage, subject, key, run_id, seconds, metrics, notes)


@dataclass(frozen=True)
class StageSpec:
    """What the record of one stage output says: its stage, its subject, settings, code version
    and upstream keys. Its key is derived from them (`storage.keys.stage_key`), so an output is
    described once.

    ``subject`` is the id of what the output is of, of the kind its stage declares
    (`tasks.registry.Subject`): a video id (ingest's and the per-video stages'), a dataset key
    (training's) or a training run's key (evaluation's). The tables keep it in their
    ``video_id`` column, the name they had when every output was a video's."""

    stage: str
    subject: str
    config: Any
    code: str
    upstream: Mapping[str, Any]

    @property
    def key(self) -> str:
        return stage_key(self.stage, self.config, self.code, self.upstream)

    @property
    def run_name(self) -> str:
        """The name of the Prefect task run that computes it."""
        return f"{self.stage}-{self.subject:.12}"


def _nothing() -> None:
    return None


def _no_arguments() -> tuple:
    return ()


@dataclass(frozen=True)
class StagePlan:
    """One stage output, planned by its stage's ``task.py`` and run by `flows.stage`.

    ``compute`` is called only when the database has no output under ``spec.key``, inside the
    stage's Prefect task, with the arguments ``before`` returns; ``before`` runs in the flow just
    before it (the pose stage tracks its chunks there, each a Prefect task of its own, and hands
    their artifacts' names to ``compute``), ``after`` in the flow whether the output was
    computed or reused. ``name`` is what the run's summary lists it by (the video's path, the
    adversary). ``noted``: the computation is noted as running, and a failure as failed, for
    `ringside status` (not ingest's: its video is registered only after it).
    """

    spec: StageSpec
    name: str
    compute: Callable[..., StageOutput]
    before: Callable[[], tuple] = _no_arguments
    after: Callable[[], None] = _nothing
    noted: bool = True


def run_stage(
    paths: DataPaths,
    spec: StageSpec,
    compute: Callable[[], StageOutput],
    run_id: str,
    started: float,
) -> StageResult:
    """Compute ``spec``'s output with ``compute`` and commit it (whether one is committed
    already is the caller's question: `flows.runs.reuse_or_run`).

    The output's ``seconds`` are its wall time from ``started`` (a `time.perf_counter` reading
    taken when the stage began, before its plan's ``before``: the pose stage tracks its chunks
    there) to the commit.

    The output's files go to the artifact store first, so that no committed row names a file
    that is not there. The database is opened only to write, never while the computation
    runs, so other processes can use it meanwhile.
    """
    output = compute()
    for name, data in output.files.items():
        if put_bytes(paths.artifacts, data, Path(name).suffix) != name:
            raise ValueError(f"{spec.stage}: file {name!r} is not named for its bytes")
    seconds = time.perf_counter() - started
    key = spec.key
    record = OutputRecord(
        spec.stage, spec.subject, key, spec.config, spec.code, spec.upstream, run_id, seconds
    )
    with connect(paths.db) as con:
        write_output(con, record, output.rows, output.metrics, output.notes)
    return StageResult(
        spec.stage,
        spec.subject,
        key,
        run_id,
        seconds,
        dict(output.metrics),
        tuple(output.notes),
    )
