"""Rows every stage shares: videos, committed stage outputs, run events and stage metrics."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import socket
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import duckdb
import numpy as np

from storage.db import transact, utcnow
from storage.keys import stable_json

RUN_STATES = ("running", "done", "cached", "failed")


@dataclass(frozen=True)
class OutputRecord:
    """What identifies one committed stage output and how it was made."""

    stage: str
    video_id: str
    key: str
    config: Any
    code_version: str
    upstream: Mapping[str, Any]
    run_id: str
    seconds: float


def register_video(con: duckdb.DuckDBPyConnection, video_id: str, size_bytes: int, path: str):
    """Record a video and the path it came from; registering it again changes nothing."""
    now = utcnow()
    # Not ON CONFLICT: a lake's tables have no primary key to conflict on.
    transact(con, lambda con: _register(con, video_id, size_bytes, path, now))


def _register(con: duckdb.DuckDBPyConnection, video_id: str, size_bytes: int, path: str, now):
    con.execute(
        "INSERT INTO videos SELECT $1, $2, $3 "
        "WHERE NOT EXISTS (SELECT 1 FROM videos WHERE video_id = $1)",
        [video_id, size_bytes, now],
    )
    con.execute(
        "INSERT INTO video_files SELECT $1, $2, $3 "
        "WHERE NOT EXISTS (SELECT 1 FROM video_files WHERE video_id = $1 AND path = $2)",
        [video_id, path, now],
    )


def output_run(
    con: duckdb.DuckDBPyConnection, stage: str, video_id: str, key: str
) -> tuple[str, float, tuple[str, ...]] | None:
    """(flow run id, seconds, notes) of the committed output ``key`` of ``stage`` for
    ``video_id``; None if there is none."""
    row = con.execute(
        "SELECT run_id, seconds, notes FROM stage_outputs "
        "WHERE stage = ? AND video_id = ? AND key = ?",
        [stage, video_id, key],
    ).fetchone()
    return None if row is None else (row[0], row[1], tuple(row[2]))


Columns = Mapping[str, np.ndarray]


def insert_records(
    con: duckdb.DuckDBPyConnection, table: str, key: str, video_id: str, records: Sequence[Any]
) -> None:
    """Insert one row per record (a dataclass instance), each field into the column of its
    name, with ``key`` and ``video_id`` filled in."""
    names = [f.name for f in dataclasses.fields(records[0])]
    insert_rows(
        con,
        f"INSERT INTO {table} (key, video_id, {', '.join(names)})",
        [[key, video_id, *(getattr(r, n) for n in names)] for r in records],
    )


# Rows per INSERT statement of `insert_rows`.
ROWS_PER_INSERT = 500


def insert_rows(con: duckdb.DuckDBPyConnection, insert: str, rows: Sequence[Sequence[Any]]) -> None:
    """``insert`` (``INSERT INTO t (a, b)``) of ``rows``, many rows per statement: a lake writes
    a Parquet file per statement, and ``executemany`` is a statement per row (30 metrics made 30
    files of one row each)."""
    for start in range(0, len(rows), ROWS_PER_INSERT):
        part = rows[start : start + ROWS_PER_INSERT]
        marks = ", ".join(["(" + ", ".join("?" * len(part[0])) + ")"] * len(part))
        con.execute(f"{insert} VALUES {marks}", [v for row in part for v in row])


def insert_columns(
    con: duckdb.DuckDBPyConnection, table: str, key: str, video_id: str, columns: Columns
) -> None:
    """Insert one row per element of the equally long ``columns`` (arrays of shape (N,) or, for
    fixed-size array columns, (N, D)), with ``key`` and ``video_id`` filled in.

    The arrays are scanned in place as a registered view: row-by-row inserts run at a few
    thousand rows per second, and so do (N, D) arrays passed as query parameters.
    """
    lengths = {name: len(values) for name, values in columns.items()}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"{table}: columns differ in length {lengths}")
    if not any(lengths.values()):
        return
    types = dict(
        con.execute(
            "SELECT column_name, data_type FROM duckdb_columns() "
            "WHERE table_name = ? AND database_name = current_database()",
            [table],
        ).fetchall()
    )
    unknown = sorted(set(columns) - set(types))
    if unknown:
        raise ValueError(f"{table} has no columns {unknown}")
    source, selects = {}, []
    for name, values in columns.items():
        array = np.asarray(values)
        select = name
        # DuckDB reads a float NaN from numpy as NULL; a float array cannot hold a NULL, so
        # every NULL that comes out of one was a NaN and is turned back into one.
        if array.ndim > 1:  # one list per row: an object array of row views, not a copy
            if np.issubdtype(array.dtype, np.floating):
                select = f"list_transform({name}, lambda v: coalesce(v, 'NaN'::DOUBLE))"
            rows = np.empty(len(array), dtype=object)
            rows[:] = list(array)
            array = rows
        elif np.issubdtype(array.dtype, np.floating):
            select = f"coalesce({name}, 'NaN'::DOUBLE)"
        source[name] = array
        selects.append(f"{select}::{types[name]}")
    view = f"_insert_{table}"
    names = list(columns)
    casts = ", ".join(selects)
    con.register(view, source)
    try:
        con.execute(
            f"INSERT INTO {table} (key, video_id, {', '.join(names)}) "
            f"SELECT $1, $2, {casts} FROM {view}",
            [key, video_id],
        )
    finally:
        con.unregister(view)


def write_output(
    con: duckdb.DuckDBPyConnection,
    record: OutputRecord,
    rows: Mapping[str, Sequence[Any] | Columns],
    metrics: Mapping[str, float],
    notes: Sequence[str] = (),
) -> None:
    """Replace the output ``record`` names, its table rows and its metrics, in one transaction.

    ``rows`` maps a stage table to its rows: records (dataclass instances whose fields are
    named as the table's columns, ``key`` and ``video_id`` left out: they are filled in) or
    :data:`Columns` (see :func:`insert_columns`). A crash leaves either the old output or the
    new one, never a mix.
    """
    bad = {name: value for name, value in metrics.items() if not math.isfinite(value)}
    if bad:
        raise ValueError(f"{record.stage}: metrics must be finite numbers, got {bad}")
    now = utcnow()
    where = [record.key, record.video_id]

    def replace(con: duckdb.DuckDBPyConnection) -> None:
        for table, table_rows in rows.items():
            con.execute(f"DELETE FROM {table} WHERE key = ? AND video_id = ?", where)
            if isinstance(table_rows, Mapping):
                insert_columns(con, table, record.key, record.video_id, table_rows)
            elif table_rows:
                insert_records(con, table, record.key, record.video_id, table_rows)
        con.execute(
            "DELETE FROM stage_outputs WHERE stage = ? AND video_id = ? AND key = ?",
            [record.stage, record.video_id, record.key],
        )
        con.execute(
            "INSERT INTO stage_outputs VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            [
                record.stage,
                record.video_id,
                record.key,
                stable_json(record.config),
                record.code_version,
                stable_json(record.upstream),
                record.run_id,
                record.seconds,
                now,
                list(notes),
            ],
        )
        con.execute(
            "DELETE FROM stage_metrics WHERE stage = ? AND video_id = ? AND key = ?",
            [record.stage, record.video_id, record.key],
        )
        if metrics:
            insert_rows(
                con,
                "INSERT INTO stage_metrics",
                [
                    [record.run_id, record.video_id, record.stage, record.key, name, float(v), now]
                    for name, v in metrics.items()
                ],
            )
        record_run(con, record.run_id, record.video_id, record.stage, record.key, "done")

    transact(con, replace)


def record_run(
    con: duckdb.DuckDBPyConnection,
    run_id: str,
    video_id: str,
    stage: str,
    key: str,
    state: str,
    error: str | None = None,
) -> None:
    """Note what run ``run_id`` did with ``stage`` of ``video_id``; a ``running`` note also names
    this process (`this_worker`), so a reader can tell whether the run is still alive."""
    if state not in RUN_STATES:
        raise ValueError(f"state must be one of {RUN_STATES}, got {state!r}")
    worker = this_worker() if state == "running" else None
    con.execute(
        "INSERT INTO stage_runs VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
        [run_id, video_id, stage, key, state, error, utcnow(), worker],
    )


def this_worker() -> str:
    """This process as ``host:pid``."""
    return f"{socket.gethostname()}:{os.getpid()}"


def worker_alive(worker: str | None) -> bool:
    """Whether the process ``host:pid`` still runs; True when it is on another host, which this
    one cannot see."""
    if not worker:
        return False
    host, _, pid = worker.rpartition(":")
    return host != socket.gethostname() or process_alive(int(pid))


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this host."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


def stale_runs(con: duckdb.DuckDBPyConnection) -> list[str]:
    """Run ids (Prefect flow run ids) of stages noted as ``running`` by a process that is gone
    without noting an end: the runs a kill left behind."""
    rows = con.execute(
        """
        SELECT r.run_id, r.worker FROM stage_runs r
        WHERE r.state = 'running' AND NOT EXISTS (
            SELECT 1 FROM stage_runs e
            WHERE e.run_id = r.run_id AND e.stage = r.stage AND e.video_id = r.video_id
              AND e.state != 'running'
        )
        """
    ).fetchall()
    return sorted({run_id for run_id, worker in rows if not worker_alive(worker)})


def latest_runs(con: duckdb.DuckDBPyConnection) -> list[dict[str, Any]]:
    """Per video and stage, the newest run event whose output still exists, or that failed or is
    running. A ``running`` event whose process has gone (killed, or crashed on a bug) reads as
    ``interrupted``; one its run saw end is no event of its own (when `check --repair` has
    removed that output, the stage reads as missing, not interrupted)."""
    rows = con.execute(
        """
        SELECT r.video_id, r.stage, r.key, r.state, r.error, r.created_at, r.worker
        FROM stage_runs r
        LEFT JOIN stage_outputs o USING (stage, video_id, key)
        WHERE r.state = 'failed' OR o.key IS NOT NULL OR (
            r.state = 'running' AND NOT EXISTS (
                SELECT 1 FROM stage_runs e
                WHERE e.run_id = r.run_id AND e.stage = r.stage AND e.video_id = r.video_id
                  AND e.key = r.key AND e.state != 'running'
            )
        )
        QUALIFY row_number() OVER (
            PARTITION BY r.video_id, r.stage ORDER BY r.created_at DESC, r.state = 'failed'
        ) = 1
        ORDER BY r.video_id, r.created_at
        """
    ).fetchall()
    names = ("video_id", "stage", "key", "state", "error", "created_at")
    runs = []
    for row in rows:
        run = dict(zip(names, row[:-1], strict=True))
        if run["state"] == "running" and not worker_alive(row[-1]):
            run["state"] = "interrupted"
            run["error"] = "its process stopped before the stage finished (killed or crashed)"
        runs.append(run)
    return runs


STATE_FIELDS = ("video_id", "stage", "key", "state", "error", "ran_at", "seconds")


def stage_states(con: duckdb.DuckDBPyConnection, stages: Sequence[str]) -> list[dict[str, Any]]:
    """One row per registered video (oldest first) and stage in ``stages``, in that order: the
    newest run's key, state (done, cached, failed, running, interrupted, or missing when no run
    left an output), error, when it ran or started (``ran_at``) and the seconds its output took to
    compute (None unless done or cached: a cached run took the seconds of the run that computed
    it)."""
    videos = [
        row[0]
        for row in con.execute("SELECT video_id FROM videos ORDER BY registered_at").fetchall()
    ]
    return _states(con, [(video_id, stage) for video_id in videos for stage in stages])


def chained_states(
    con: duckdb.DuckDBPyConnection, subjects: Sequence[str], chain: Sequence[str]
) -> list[dict[str, Any]]:
    """The rows `stage_states` gives, for stages whose subject is the output of the stage
    before (`tasks.registry`: training's is a dataset, evaluation's a training run): per
    subject of ``chain[0]`` (in the order given) its newest output, and after each finished
    one, the same for the rest of the chain on that output's key (``video_id`` is the subject,
    as in ``stage_runs``)."""
    state = _state_reader(con)

    def walk(subjects: Sequence[str], chain: Sequence[str]) -> list[dict[str, Any]]:
        rows = []
        for subject in subjects if chain else ():
            row = state(subject, chain[0])
            rows.append(row)
            if row["state"] in ("done", "cached"):
                rows += walk([row["key"]], chain[1:])
        return rows

    return walk(subjects, chain)


def _states(
    con: duckdb.DuckDBPyConnection, wanted: Sequence[tuple[str, str]]
) -> list[dict[str, Any]]:
    """One `STATE_FIELDS` row per (video_id, stage) in ``wanted``."""
    state = _state_reader(con)
    return [state(video_id, stage) for video_id, stage in wanted]


def _state_reader(con: duckdb.DuckDBPyConnection) -> Callable[[str, str], dict[str, Any]]:
    """A function of (video_id, stage) giving its `STATE_FIELDS` row, from the newest runs and
    the outputs' seconds read once."""
    runs = {(r["video_id"], r["stage"]): r for r in latest_runs(con)}
    seconds = {
        (stage, video_id, key): value
        for stage, video_id, key, value in con.execute(
            "SELECT stage, video_id, key, seconds FROM stage_outputs"
        ).fetchall()
    }

    def state(video_id: str, stage: str) -> dict[str, Any]:
        run = runs.get((video_id, stage))
        if run is None:
            missing = {"video_id": video_id, "stage": stage, "state": "missing"}
            return {**dict.fromkeys(STATE_FIELDS), **missing}
        finished = run["state"] in ("done", "cached")
        took = seconds.get((stage, video_id, run["key"])) if finished else None
        return {
            **{name: run[name] for name in ("video_id", "stage", "key", "state", "error")},
            "ran_at": run["created_at"],
            "seconds": took,
        }

    return state


def latest_metrics(con: duckdb.DuckDBPyConnection, stage: str | None = None) -> list[dict]:
    """Metrics of the newest committed output per video and stage."""
    rows = con.execute(
        """
        WITH newest AS (
            SELECT stage, video_id, key FROM stage_outputs
            QUALIFY row_number() OVER (PARTITION BY stage, video_id ORDER BY created_at DESC) = 1
        )
        SELECT m.video_id, m.stage, m.key, m.name, m.value
        FROM stage_metrics m JOIN newest USING (stage, video_id, key)
        WHERE ? IS NULL OR m.stage = ?
        ORDER BY m.video_id, m.stage, m.name
        """,
        [stage, stage],
    ).fetchall()
    names = ("video_id", "stage", "key", "name", "value")
    return [dict(zip(names, row, strict=True)) for row in rows]


def output_metrics(
    con: duckdb.DuckDBPyConnection, stage: str, video_id: str, key: str
) -> dict[str, float]:
    """The metrics of one committed output, by name (in name order)."""
    rows = con.execute(
        "SELECT name, value FROM stage_metrics WHERE stage = ? AND video_id = ? AND key = ? "
        "ORDER BY name",
        [stage, video_id, key],
    ).fetchall()
    return dict(rows)


def output_config(con: duckdb.DuckDBPyConnection, stage: str, video_id: str, key: str) -> dict:
    row = con.execute(
        "SELECT config FROM stage_outputs WHERE stage = ? AND video_id = ? AND key = ?",
        [stage, video_id, key],
    ).fetchone()
    if row is None:
        raise KeyError(f"no {stage} output {key} for video {video_id}")
    return json.loads(row[0])


def output_history(
    con: duckdb.DuckDBPyConnection, stage: str, video_id: str
) -> list[dict[str, Any]]:
    """The committed outputs of ``stage`` for ``video_id`` (a video, or a dataset or run key),
    newest first: key, created_at, seconds and metrics (name -> value)."""
    rows = con.execute(
        "SELECT key, created_at, seconds FROM stage_outputs WHERE stage = ? AND video_id = ? "
        "ORDER BY created_at DESC",
        [stage, video_id],
    ).fetchall()
    return [
        {
            "key": key,
            "created_at": created_at,
            "seconds": seconds,
            "metrics": output_metrics(con, stage, video_id, key),
        }
        for key, created_at, seconds in rows
    ]


def stages_finished_since(
    con: duckdb.DuckDBPyConnection, video_id: str, since: datetime, stages: Sequence[str]
) -> list[str]:
    """Which of ``stages`` some run has finished (done or cached) since ``since`` (UTC) for
    ``video_id``, in their order: its own, training on a dataset it is a member of, and the
    evaluation of a run trained on one."""
    found = {
        row[0]
        for row in con.execute(
            """
            WITH sets AS (SELECT dataset_key FROM dataset_members WHERE video_id = $video),
            runs AS (
                SELECT key FROM stage_outputs
                WHERE stage = 'train' AND video_id IN (SELECT dataset_key FROM sets)
            )
            SELECT DISTINCT stage FROM stage_runs
            WHERE created_at >= $since AND state IN ('done', 'cached') AND (
                video_id = $video
                OR (stage = 'train' AND video_id IN (SELECT dataset_key FROM sets))
                OR (stage = 'evaluate' AND video_id IN (SELECT key FROM runs))
            )
            """,
            {"video": video_id, "since": since},
        ).fetchall()
    }
    return [stage for stage in stages if stage in found]


def newest_output(
    con: duckdb.DuckDBPyConnection, stage: str, video_id: str
) -> tuple[str, dict[str, Any]] | None:
    """(key, upstream keys) of the newest committed output of ``stage`` for ``video_id``."""
    row = con.execute(
        "SELECT key, upstream FROM stage_outputs WHERE stage = ? AND video_id = ? "
        "ORDER BY created_at DESC LIMIT 1",
        [stage, video_id],
    ).fetchone()
    return None if row is None else (row[0], json.loads(row[1]))
