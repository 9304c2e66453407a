"""What the dashboard shows, as pure functions of a DuckDB connection.

A page opens one short read-only connection, calls these, closes it and only then draws, so
the pipeline can take the database's write lock between two renders. Where the CLI prints the
same thing, these call the CLI's own queries (`storage.records`, `tasks.dataset.store`,
`tasks.train.run`), so the dashboard and `ringside status`, `metrics`, `datasets` and `curves`
cannot disagree.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import duckdb
import numpy as np
import pandas as pd

from flows.config import PIPELINE_STAGES, SECTIONS, STAGES
from models.pose.types import BLAZEPOSE_33
from storage.records import (
    latest_metrics,
    opponent_states,
    output_metrics,
    stage_states,
    worker_alive,
)
from tasks.dataset.statistics import FighterStatistics
from tasks.dataset.store import list_datasets, member_statistics
from tasks.evaluate.store import evaluation_tables
from tasks.lift.store import lift_series
from tasks.pose.store import newest_pick
from tasks.train.store import learning_curves

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


def opponent_overview(con: duckdb.DuckDBPyConnection) -> list[dict[str, Any]]:
    """Per dataset (oldest first) its newest training run, and the evaluation of each finished
    one: the rows `ringside status` prints after the videos', with the dataset's adversary."""
    datasets = {d["dataset_key"]: d["adversary"] for d in reversed(list_datasets(con))}
    rows = opponent_states(con, list(datasets))
    adversary: dict[str, str] = dict(datasets)
    for row in rows:
        if row["stage"] == "train":
            adversary[row["key"]] = datasets[row["video_id"]]
    return [{**row, "adversary": adversary.get(row["video_id"], "")} for row in rows]


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
    dataset key, adversary, iterations so far, when it last saved and its state: ``finished``
    (committed its policy as the train stage's output), ``running`` (its process is alive) or
    ``interrupted`` (its process is gone: the same command resumes it from its checkpoint)."""
    rows = con.execute(
        """
        WITH runs AS (
            SELECT key, video_id, max(iteration) + 1 AS iterations
            FROM train_iterations GROUP BY ALL
        ), saved AS (
            SELECT key, video_id, max(created_at) AS saved_at FROM train_checkpoints GROUP BY ALL
        ), started AS (
            SELECT key, video_id, arg_max(worker, created_at) AS worker
            FROM stage_runs WHERE stage = 'train' AND state = 'running' GROUP BY ALL
        )
        SELECT r.key, r.video_id, d.adversary, r.iterations, s.saved_at, o.key IS NOT NULL,
               w.worker
        FROM runs r
        LEFT JOIN saved s USING (key, video_id)
        LEFT JOIN started w USING (key, video_id)
        LEFT JOIN datasets d ON d.dataset_key = r.video_id
        LEFT JOIN stage_outputs o ON o.stage = 'train' AND o.key = r.key AND o.video_id = r.video_id
        ORDER BY s.saved_at DESC NULLS LAST, r.key
        """
    ).fetchall()
    names = ("key", "dataset_key", "adversary", "iterations", "saved_at")
    runs = []
    for *row, finished, worker in rows:
        state = "finished" if finished else "running" if worker_alive(worker) else "interrupted"
        runs.append({**dict(zip(names, row, strict=True)), "state": state})
    return runs


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


def outputs(con: duckdb.DuckDBPyConnection, stage: str, video_id: str) -> list[dict[str, Any]]:
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


def against_previous(history: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """The newest output's metrics beside the previous output's (`outputs` order), with the
    change; empty without two outputs."""
    if len(history) < 2:
        return pd.DataFrame()
    newest, previous = history[0]["metrics"], history[1]["metrics"]
    names = sorted(set(newest) | set(previous))
    frame = pd.DataFrame(
        {
            "newest": [newest.get(n, math.nan) for n in names],
            "previous": [previous.get(n, math.nan) for n in names],
        },
        index=names,
    )
    frame["change"] = frame["newest"] - frame["previous"]
    return frame


@dataclass(frozen=True)
class PoseReview:
    """What the Pose page shows of one pose output.

    Attributes:
        key: the pose output's key.
        overlay: artifact name of the overlay MP4 (None if the output has none).
        stills: (frame, PNG artifact name) pairs.
        tracks: one row per track: track, shot, role, first_frame, last_frame, frames_observed.
        cuts: the frames where a new shot starts (after the first).
        handovers: frame, role, from_track, to_track: where a fighter's keypoints move from one
            track to another.
        confidence: role, joint (BlazePose name), mean estimator confidence over tracked frames.
        pick: the analyst's newest adversary track for the video, if any.
    """

    key: str
    overlay: str | None
    stills: list[tuple[int, str]]
    tracks: pd.DataFrame
    cuts: list[int]
    handovers: pd.DataFrame
    confidence: pd.DataFrame
    pick: int | None


def pose_review(con: duckdb.DuckDBPyConnection, video_id: str) -> PoseReview | None:
    """The newest pose output of ``video_id`` as the Pose page shows it; None if there is none."""
    history = con.execute(
        "SELECT key, upstream FROM stage_outputs WHERE stage = 'pose' AND video_id = ? "
        "ORDER BY created_at DESC LIMIT 1",
        [video_id],
    ).fetchone()
    if history is None:
        return None
    key, upstream = history[0], json.loads(history[1])
    where = [key, video_id]
    media = con.execute(
        "SELECT kind, frame, artifact FROM pose_media WHERE key = ? AND video_id = ? "
        "ORDER BY kind, frame",
        where,
    ).fetchall()
    tracks = con.execute(
        "SELECT track, shot, role, first_frame, last_frame, frames_observed FROM pose_tracks "
        "WHERE key = ? AND video_id = ? ORDER BY first_frame, track",
        where,
    ).df()
    cuts = [
        row[0]
        for row in con.execute(
            "SELECT start_frame FROM ingest_shots WHERE key = ? AND video_id = ? AND shot > 0 "
            "ORDER BY shot",
            [upstream["ingest"], video_id],
        ).fetchall()
    ]
    handovers = con.execute(
        """
        WITH seen AS (
            SELECT frame, role, track,
                   lag(track) OVER (PARTITION BY role ORDER BY frame) AS from_track
            FROM pose_keypoints WHERE key = ? AND video_id = ? AND track >= 0
        )
        SELECT frame, role, from_track, track AS to_track FROM seen
        WHERE from_track IS NOT NULL AND from_track <> track ORDER BY frame, role
        """,
        where,
    ).df()
    confidence = con.execute(
        """
        SELECT role, joint - 1 AS joint, avg(raw_confidence[joint]) AS confidence
        FROM pose_keypoints, range(1, 34) AS joints(joint)
        WHERE key = ? AND video_id = ? AND track >= 0 AND isfinite(raw_confidence[joint])
        GROUP BY ALL ORDER BY role, joint
        """,
        where,
    ).df()
    confidence["joint"] = [BLAZEPOSE_33[i] for i in confidence["joint"]]
    return PoseReview(
        key=key,
        overlay=next((a for kind, _, a in media if kind == "overlay"), None),
        stills=[(frame, a) for kind, frame, a in media if kind == "still"],
        tracks=tracks,
        cuts=cuts,
        handovers=handovers,
        confidence=confidence,
        pick=newest_pick(con, video_id),
    )


def stages_finished_since(
    con: duckdb.DuckDBPyConnection, video_id: str, since: datetime
) -> list[str]:
    """The stages some run has finished (done or cached) since ``since`` (UTC) for ``video_id``,
    in pipeline order: its own, training on a dataset it is a member of, and the evaluation of
    a run trained on one."""
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
    return [stage for stage in PIPELINE_STAGES if stage in found]


def evaluations(con: duckdb.DuckDBPyConnection) -> list[dict[str, Any]]:
    """The newest evaluation of each evaluated training run, newest first: run_key, key
    (the evaluation's), created_at and its metrics."""
    rows = con.execute(
        """
        SELECT video_id, key, created_at FROM stage_outputs WHERE stage = 'evaluate'
        QUALIFY row_number() OVER (PARTITION BY video_id ORDER BY created_at DESC) = 1
        ORDER BY created_at DESC
        """
    ).fetchall()
    return [
        {
            "run_key": run_key,
            "key": key,
            "created_at": created_at,
            "metrics": output_metrics(con, "evaluate", run_key, key),
        }
        for run_key, key, created_at in rows
    ]


def evaluation(con: duckdb.DuckDBPyConnection, key: str, run_key: str) -> dict[str, list[dict]]:
    """The evaluation tables `ringside evaluate` prints (`evaluation_tables`)."""
    return evaluation_tables(con, key, run_key)


# The cleanup measures the Lift page charts (series columns are "MEASURE|FIGHTER").
DISTANCE = "distance between fighters (m)"
SKATING = "foot skating, feet in contact (m/s)"
PENETRATION = "floor penetration (m)"


@dataclass(frozen=True)
class LiftReview:
    """What the Lift page shows of one lift output: its key, the MP4 of both humanoids (an
    artifact name, None if absent), its metrics and the cleanup measures per step in one frame
    (index: seconds into the video; columns: measure and fighter)."""

    key: str
    video: str | None
    metrics: dict[str, float]
    series: pd.DataFrame

    @property
    def seconds(self) -> float:
        """How long the series run: steps times the grid's step."""
        time_s = self.series.index
        return float(len(time_s) * (time_s[1] - time_s[0])) if len(time_s) > 1 else 0.0

    @property
    def tiles(self) -> dict[str, float]:
        """The page's headline numbers, each a summary of a charted series, so that a tile and
        its chart always agree (the stage's own summary metrics are measured at the video's
        frame rate, before resampling to the 30 Hz grid the series are on)."""

        def values(measure: str) -> np.ndarray:
            columns = [c for c in self.series.columns if c.split("|")[0] == measure]
            return self.series[columns].to_numpy(dtype=float).ravel()

        def summary(reduce, measure: str, scale: float = 1.0) -> float:
            found = values(measure)
            return float(reduce(found)) * scale if np.isfinite(found).any() else math.nan

        return {
            "Mean distance (m)": summary(np.nanmean, DISTANCE),
            "Mean foot skating (m/s)": summary(np.nanmean, SKATING),
            "Deepest penetration (mm)": summary(np.nanmax, PENETRATION, 1000.0),
        }


def lift_review(con: duckdb.DuckDBPyConnection, video_id: str) -> LiftReview | None:
    """The newest lift output of ``video_id`` as the Lift page shows it; None if there is none."""
    history = outputs(con, "lift", video_id)
    if not history:
        return None
    key = history[0]["key"]
    media = dict(
        con.execute(
            "SELECT kind, artifact FROM lift_media WHERE key = ? AND video_id = ?", [key, video_id]
        ).fetchall()
    )
    measured = lift_series(con, key, video_id)
    columns: dict[tuple[str, str], Any] = {(DISTANCE, "both"): measured.fighter_distance_m}
    for role, fighter in measured.fighters.items():
        slide = fighter.contact_slide_m_s
        # A step's skating: the faster sliding foot of those in contact (NaN with both in the air).
        any_contact = ~np.isnan(slide).all(axis=1)
        fastest = np.full(len(slide), np.nan)
        fastest[any_contact] = np.nanmax(slide[any_contact], axis=1)
        columns[(SKATING, role)] = fastest
        columns[(PENETRATION, role)] = fighter.floor_penetration_m
    series = pd.DataFrame(
        {f"{measure}|{role}": values for (measure, role), values in columns.items()},
        index=pd.Index(measured.time_s, name="time_s"),
    )
    return LiftReview(key, media.get("video"), history[0]["metrics"], series)
