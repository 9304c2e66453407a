"""What the evaluate stage reads from the database: training runs, the adversary's real
statistics, and its own tables for showing. No torch here, so the flow can check its input fast.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import duckdb

from storage.records import newest_output, output_metrics
from tasks.dataset.statistics import FighterStatistics
from tasks.dataset.store import member_statistics
from tasks.errors import BadInput
from tasks.train.store import RunInfo, finished_run, finished_runs

STAGE = "evaluate"
# The tables the stage fills, in the order they are shown.
TABLES = (
    "evaluate_damage",
    "evaluate_heading",
    "evaluate_style",
    "evaluate_boxing",
    "evaluate_classifier",
    "evaluate_artifacts",
)
# Control tasks whose runs join the damage table (MAAIP Table 1) beside the evaluated run's.
DAMAGE_TASKS = ("damage_min", "damage_max")


@dataclass(frozen=True)
class DamageRow:
    """An ``evaluate_damage`` row: one agent's mean damage per episode in a run's bouts."""

    run_key: str
    control_task: str
    agent: int
    received_n: float
    dealt_n: float
    episodes: int
    frames: int


@dataclass(frozen=True)
class HeadingRow:
    """An ``evaluate_heading`` row: one agent's normalised heading return in a heading run."""

    run_key: str
    motion_prior: bool
    agent: int
    normalized_return: float
    episodes: int
    frames: int


@dataclass(frozen=True)
class StyleDistanceRow:
    """An ``evaluate_style`` row: a simulated fighter's statistic against the footage's."""

    policy: str
    statistic: str
    kind: str
    simulated: float
    real: float
    distance: float


@dataclass(frozen=True)
class BoxingRow:
    """An ``evaluate_boxing`` row: one boxing metric of a simulated fighter."""

    policy: str
    metric: str
    value: float


@dataclass(frozen=True)
class ClassifierRow:
    """An ``evaluate_classifier`` row: the two-sample test of one fighter's windows against a
    reference ('footage': the adversary's held-out footage; 'replay': the tracker's replay of
    it), or NULL and the reason it could not be made. Policy 'train' is the reference's own
    train split (train footage, or the replay of the train clips): the real-against-real level,
    what a perfect answer would score."""

    policy: str
    auc: float | None
    auc_low: float | None
    auc_high: float | None
    real_windows: int
    simulated_windows: int
    reason: str | None
    telltales: str | None = None
    reference: str = "footage"
    feature_gap: float | None = None


@dataclass(frozen=True)
class ArtifactRow:
    """An ``evaluate_artifacts`` row: a file of the evaluation in the artifact store."""

    name: str
    artifact: str


def resolve_run(con: duckdb.DuckDBPyConnection, run: str) -> RunInfo:
    """The finished training run whose key starts with ``run``; BadInput if none or several."""
    found = finished_run(con, run, "--run")
    if found.objective != "maaip":
        raise BadInput(
            f"--run {run}",
            f"is a {found.objective!r} run (train.objective), which follows clips and "
            "fights no one; evaluate or export a MAAIP run (its clips: "
            "`ringside metrics --stage train`)",
        )
    return found


def compared_runs(con: duckdb.DuckDBPyConnection, run: RunInfo) -> list[RunInfo]:
    """Other finished runs on ``run``'s dataset that the tables compare with it: damage
    minimising and maximising runs (Table 1) and heading runs (Table 2), oldest first."""
    others = finished_runs(con, "p.video_id = ? AND p.key != ?", [run.dataset_key, run.run_key])
    return [
        other
        for other in others
        if other.objective == "maaip" and other.control_task in (*DAMAGE_TASKS, "heading")
    ]


def real_statistics(
    con: duckdb.DuckDBPyConnection, dataset_key: str, role: str = "adversary"
) -> FighterStatistics:
    """The ``role``'s statistics over dataset ``dataset_key``'s footage (`member_statistics`)."""
    _, combined = member_statistics(con, dataset_key)
    if role not in combined:
        raise BadInput(
            f"dataset {dataset_key}",
            f"holds no statistics of the {role}: nothing to compare the simulated style with",
        )
    return combined[role]


def evaluation_tables(
    con: duckdb.DuckDBPyConnection, key: str, run_key: str
) -> dict[str, list[dict]]:
    """The rows of every evaluate table for evaluation ``key`` of run ``run_key``, as dicts
    (table name without its 'evaluate_' prefix -> rows)."""
    out = {}
    for table in TABLES:
        cursor = con.execute(
            f"SELECT * EXCLUDE (key, video_id) FROM {table} WHERE key = ? AND video_id = ? "
            "ORDER BY ALL",
            [key, run_key],
        )
        names = [d[0] for d in cursor.description]
        out[table.removeprefix("evaluate_")] = [
            dict(zip(names, row, strict=True)) for row in cursor.fetchall()
        ]
    return out


def newest_evaluation(con: duckdb.DuckDBPyConnection, run_key: str) -> str | None:
    """The key of the newest committed evaluation of training run ``run_key``, or None."""
    newest = newest_output(con, STAGE, run_key)
    return None if newest is None else newest[0]


def evaluation_artifacts(con: duckdb.DuckDBPyConnection, key: str, run_key: str) -> dict[str, str]:
    """The files evaluation ``key`` of run ``run_key`` stored: name -> artifact."""
    return dict(
        con.execute(
            "SELECT name, artifact FROM evaluate_artifacts WHERE key = ? AND video_id = ? "
            "ORDER BY name",
            [key, run_key],
        ).fetchall()
    )


def newest_evaluations(con: duckdb.DuckDBPyConnection) -> list[dict[str, Any]]:
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
