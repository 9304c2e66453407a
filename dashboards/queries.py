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
from datetime import datetime
from typing import Any

import duckdb
import numpy as np
import pandas as pd

from models.pose.types import BLAZEPOSE_33
from storage.records import (
    chained_states,
    latest_metrics,
    newest_output,
    output_history,
    stage_states,
)
from storage.records import stages_finished_since as finished_since
from tasks.dataset.statistics import FighterStatistics
from tasks.dataset.store import list_datasets, member_statistics
from tasks.evaluate.store import evaluation_tables, newest_evaluations
from tasks.ingest.store import shot_starts, video_list
from tasks.lift.store import lift_media, lift_series
from tasks.pose.store import (
    joint_confidence,
    newest_pick,
    pose_media,
    pose_tracks,
    track_handovers,
)
from tasks.registry import Subject, names, per_video
from tasks.train import store as train_store


def metric_stages() -> tuple[str, ...]:
    """Every stage, in pipeline order (`tasks.registry`): the ones `ringside metrics --stage`
    knows. A per-video stage's output belongs to a video; training's to a dataset and
    evaluation's to a training run, whose keys stand in the "video_id" column."""
    return names()


# Points a learning curve is drawn with by default, whatever the run's length.
CURVE_POINTS = 100


def short(key: str | None) -> str:
    """A key or id as the CLI prints it: its first 12 characters."""
    return "" if key is None else key[:12]


def videos(con: duckdb.DuckDBPyConnection) -> list[dict[str, Any]]:
    """Every registered video, oldest first (`tasks.ingest.store.video_list`)."""
    return video_list(con)


def stage_overview(con: duckdb.DuckDBPyConnection) -> list[dict[str, Any]]:
    """Per video and per-video stage: the newest run's state, key, error and timings, the rows
    `ringside status` prints (see `storage.records.stage_states`)."""
    return stage_states(con, per_video())


def opponent_overview(con: duckdb.DuckDBPyConnection) -> list[dict[str, Any]]:
    """Per dataset (oldest first) its newest training run, and the evaluation of each finished
    one (the stages of a dataset and of a run): the rows `ringside status` prints after the
    videos', each with its dataset's adversary."""
    datasets = {d["dataset_key"]: d["adversary"] for d in reversed(list_datasets(con))}
    rows = chained_states(con, list(datasets), names(Subject.DATASET, Subject.RUN))
    adversary: dict[str, str] = dict(datasets)
    for row in rows:  # each after the row whose output is its subject
        if row["key"]:
            adversary[row["key"]] = adversary.get(row["video_id"], "")
    return [{**row, "adversary": adversary.get(row["video_id"], "")} for row in rows]


def state_matrix(states: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """Videos × stages, each cell the stage's state; rows in the order of ``states``."""
    if not states:
        return pd.DataFrame(columns=list(per_video()))
    frame = pd.DataFrame(states)
    matrix = frame.pivot(index="video_id", columns="stage", values="state")
    order = list(dict.fromkeys(frame["video_id"]))
    stages = [s for s in per_video() if s in matrix.columns]
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


def dataset_tracking(con: duckdb.DuckDBPyConnection, dataset_key: str) -> tuple[str, list[dict]]:
    """Each clip's tracking error by the dataset's newest tracker run
    (`tasks.train.store.dataset_tracking`)."""
    return train_store.dataset_tracking(con, dataset_key)


def training_runs(con: duckdb.DuckDBPyConnection) -> list[dict[str, Any]]:
    """Every training run, the newest checkpoint first (`tasks.train.store.training_runs`)."""
    return train_store.training_runs(con)


def default_every(iterations: int) -> int:
    """Iterations averaged per point so that a run's curve has about `CURVE_POINTS` points."""
    return max(1, math.ceil(iterations / CURVE_POINTS))


def curves(con: duckdb.DuckDBPyConnection, key: str, *, every: int) -> list[dict[str, Any]]:
    """Run ``key``'s learning curves averaged over blocks of ``every`` iterations, the rows
    `ringside curves --run KEY --every N --json` prints."""
    return train_store.learning_curves(con, key, every=every)


def gate_checks(con: duckdb.DuckDBPyConnection, key: str) -> list[dict[str, Any]]:
    """Tracker run ``key``'s gate checks, oldest first (`tasks.train.store.gate_checks`)."""
    return train_store.gate_checks(con, key)


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
    """The committed outputs of ``stage`` for ``video_id``, newest first
    (`storage.records.output_history`)."""
    return output_history(con, stage, video_id)


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
    newest = newest_output(con, "pose", video_id)
    if newest is None:
        return None
    key, upstream = newest
    media = pose_media(con, key, video_id)
    tracks = pd.DataFrame(
        pose_tracks(con, key, video_id),
        columns=["track", "shot", "role", "first_frame", "last_frame", "frames_observed"],
    )
    cuts = shot_starts(con, upstream["ingest"], video_id)
    handovers = pd.DataFrame(
        track_handovers(con, key, video_id), columns=["frame", "role", "from_track", "to_track"]
    )
    confidence = pd.DataFrame(
        joint_confidence(con, key, video_id), columns=["role", "joint", "confidence"]
    )
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


def evaluation(con: duckdb.DuckDBPyConnection, key: str, run_key: str) -> dict[str, list[dict]]:
    """The evaluation tables `ringside evaluate` prints (`evaluation_tables`)."""
    return evaluation_tables(con, key, run_key)


def stages_finished_since(
    con: duckdb.DuckDBPyConnection, video_id: str, since: datetime
) -> list[str]:
    """The pipeline's stages some run has finished for ``video_id`` since ``since`` (UTC)
    (`storage.records.stages_finished_since`)."""
    return finished_since(con, video_id, since, names())


def evaluations(con: duckdb.DuckDBPyConnection) -> list[dict[str, Any]]:
    """The newest evaluation of each evaluated run (`tasks.evaluate.store.newest_evaluations`)."""
    return newest_evaluations(con)


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
    media = lift_media(con, key, video_id)
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
