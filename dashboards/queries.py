"""What the dashboard shows, as pure functions of a DuckDB connection.

A page opens one short read-only connection, calls these, closes it and only then draws, so
the pipeline can take the database's write lock between two renders. Where the CLI prints the
same thing, these call the CLI's own queries (`storage.records`, `tasks.dataset.store`,
`tasks.train.run`), so the dashboard and `ringside status`, `metrics`, `datasets` and `curves`
cannot disagree.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import duckdb
import pandas as pd

from flows.config import SECTIONS, STAGES
from storage.records import latest_metrics, stage_states
from tasks.dataset.statistics import FighterStatistics
from tasks.dataset.store import list_datasets, member_statistics
from tasks.train.run import learning_curves

# Every stage, in pipeline order (a stage has its config section once it exists): the ones
# `ringside metrics --stage` knows. A per-video stage's output belongs to a video; training's
# to a dataset and evaluation's to a training run, whose keys stand in the "video_id" column.
METRIC_STAGES: tuple[str, ...] = tuple(SECTIONS)
# Points a learning curve is drawn with by default, whatever the run's length.
CURVE_POINTS = 100


def short(key: str | None) -> str:
    """A key or id as the CLI prints it: its first 12 characters."""
    return "" if key is None else key[:12]


def videos(con: duckdb.DuckDBPyConnection) -> list[dict[str, Any]]:
    """Every registered video, oldest first: its id, the newest path it was registered from and
    the adversary its newest ingest output names (None before ingest has finished)."""
    rows = con.execute(
        """
        WITH files AS (
            SELECT video_id, path FROM video_files
            QUALIFY row_number() OVER (PARTITION BY video_id ORDER BY registered_at DESC) = 1
        ), adversaries AS (
            SELECT a.video_id, a.name FROM ingest_adversaries a
            JOIN stage_outputs o ON o.stage = 'ingest' AND o.key = a.key AND o.video_id = a.video_id
            QUALIFY row_number() OVER (PARTITION BY a.video_id ORDER BY o.created_at DESC) = 1
        )
        SELECT v.video_id, f.path, a.name
        FROM videos v LEFT JOIN files f USING (video_id) LEFT JOIN adversaries a USING (video_id)
        ORDER BY v.registered_at, v.video_id
        """
    ).fetchall()
    return [dict(zip(("video_id", "path", "adversary"), row, strict=True)) for row in rows]


def stage_overview(con: duckdb.DuckDBPyConnection) -> list[dict[str, Any]]:
    """Per video and per-video stage: the newest run's state, key, error and timings, the rows
    `ringside status` prints (see `storage.records.stage_states`)."""
    return stage_states(con, STAGES)


def state_matrix(states: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """Videos × stages, each cell the stage's state; rows in the order of ``states``."""
    if not states:
        return pd.DataFrame(columns=list(STAGES))
    frame = pd.DataFrame(states)
    matrix = frame.pivot(index="video_id", columns="stage", values="state")
    order = list(dict.fromkeys(frame["video_id"]))
    stages = [s for s in STAGES if s in matrix.columns]
    return matrix.loc[order, stages]


def stage_metrics(con: duckdb.DuckDBPyConnection, stage: str) -> list[dict[str, Any]]:
    """The rows `ringside metrics --stage STAGE --json` prints: the metrics of each video's (for
    train: each dataset's) newest output."""
    return latest_metrics(con, stage)


def metrics_table(rows: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """Metrics rows as a table: one row per metric name (sorted), one column per video id (or
    dataset key) in the order the rows give them, the values as floats."""
    if not rows:
        return pd.DataFrame()
    frame = pd.DataFrame(rows)
    table = frame.pivot(index="name", columns="video_id", values="value")
    return table[list(dict.fromkeys(frame["video_id"]))]


def datasets(con: duckdb.DuckDBPyConnection) -> list[dict[str, Any]]:
    """Every assembled dataset, newest first, as `ringside datasets` lists them."""
    return list_datasets(con)


@dataclass(frozen=True)
class DatasetStatistics:
    """The fighters' statistics (`tasks.dataset.statistics`) over one assembled dataset.

    Attributes:
        per_video: one row per member video, role and statistic: video_id, role, name, value.
        combined: role -> the statistics over all member videos (`combine`: rates and per-frame
            means weighted by each video's minutes, distributions concatenated).
    """

    per_video: pd.DataFrame
    combined: dict[str, FighterStatistics]


def dataset_statistics(con: duckdb.DuckDBPyConnection, dataset_key: str) -> DatasetStatistics:
    """Each fighter's statistics in the member videos of dataset ``dataset_key``, and combined."""
    rows, combined = member_statistics(con, dataset_key)
    per_video = pd.DataFrame(rows, columns=["video_id", "role", "name", "value"])
    return DatasetStatistics(per_video, combined)


def training_runs(con: duckdb.DuckDBPyConnection) -> list[dict[str, Any]]:
    """Every training run that has recorded iterations, the newest checkpoint first: its key,
    dataset key, adversary, iterations so far, when it last saved and whether it has finished
    (committed its policy as the train stage's output) or is still going or was stopped."""
    rows = con.execute(
        """
        WITH runs AS (
            SELECT key, video_id, max(iteration) + 1 AS iterations
            FROM train_iterations GROUP BY ALL
        ), saved AS (
            SELECT key, video_id, max(created_at) AS saved_at FROM train_checkpoints GROUP BY ALL
        )
        SELECT r.key, r.video_id, d.adversary, r.iterations, s.saved_at, o.key IS NOT NULL
        FROM runs r
        LEFT JOIN saved s USING (key, video_id)
        LEFT JOIN datasets d ON d.dataset_key = r.video_id
        LEFT JOIN stage_outputs o ON o.stage = 'train' AND o.key = r.key AND o.video_id = r.video_id
        ORDER BY s.saved_at DESC NULLS LAST, r.key
        """
    ).fetchall()
    names = ("key", "dataset_key", "adversary", "iterations", "saved_at", "finished")
    return [dict(zip(names, row, strict=True)) for row in rows]


def default_every(iterations: int) -> int:
    """Iterations averaged per point so that a run's curve has about `CURVE_POINTS` points."""
    return max(1, math.ceil(iterations / CURVE_POINTS))


def curves(con: duckdb.DuckDBPyConnection, key: str, *, every: int) -> list[dict[str, Any]]:
    """Run ``key``'s learning curves averaged over blocks of ``every`` iterations, the rows
    `ringside curves --run KEY --every N --json` prints."""
    return learning_curves(con, key, every=every)


def curves_frame(rows: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """Curve rows as a frame indexed by each block's first iteration, one column per curve."""
    if not rows:
        return pd.DataFrame()
    frame = pd.DataFrame(rows)
    frame.index = pd.Index(
        [int(label.split("-")[0]) for label in frame.pop("iterations")], name="iteration"
    )
    return frame
