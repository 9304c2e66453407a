"""The train stage's SQL: a run's checkpoints and per-iteration metrics, the run to warm-start
from, and a run's learning curves."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import duckdb

from storage.db import utcnow
from storage.records import Columns, insert_columns, worker_alive
from tasks.config import build
from tasks.dataset.store import training_bones
from tasks.errors import BadInput
from tasks.train.config import TrainConfig


@dataclass(frozen=True)
class PolicyRow:
    """A ``train_policies`` row: a finished run's final checkpoint."""

    iteration: int
    artifact: str


@dataclass(frozen=True)
class RunInfo:
    """A finished training run: its key, its dataset's, its final iteration and policy (an
    artifact), its settings (the `train` section)."""

    run_key: str
    dataset_key: str
    iteration: int
    artifact: str
    config: dict

    @property
    def control_task(self) -> str:
        return self.config.get("reward", {}).get("control_task", "none")

    @property
    def objective(self) -> str:
        return self.config.get("objective", "maaip")


def finished_runs(con: duckdb.DuckDBPyConnection, where: str, params: list) -> list[RunInfo]:
    """The finished training runs matching SQL ``where`` (over ``train_policies p``), oldest
    first."""
    rows = con.execute(
        "SELECT p.key, p.video_id, p.iteration, p.artifact, o.config FROM train_policies p "
        "JOIN stage_outputs o ON o.stage = 'train' AND o.key = p.key "
        f"AND o.video_id = p.video_id WHERE {where} ORDER BY o.created_at, p.key",
        params,
    ).fetchall()
    return [RunInfo(*row[:4], json.loads(row[4])) for row in rows]


def finished_run(con: duckdb.DuckDBPyConnection, run: str, setting: str) -> RunInfo:
    """The finished training run whose key starts with ``run``; BadInput naming ``setting``
    (the flag or setting that gave it) if it matches none or several."""
    found = finished_runs(con, "p.key LIKE ? || '%'", [run])
    if len(found) != 1:
        problem = "matches no finished training run" if not found else "matches several runs"
        raise BadInput(f"{setting} {run}", f"{problem}; see `ringside metrics --stage train`")
    return found[0]


def named_warm_start(con: duckdb.DuckDBPyConnection, run: str, config: TrainConfig) -> RunInfo:
    """The finished run ``run`` (a key or a prefix of one) that a run with `train.warm_from`
    starts from; BadInput when it names no finished run, several, or one of other networks."""
    found = finished_run(con, run, "train.warm_from")
    if not _fits(found.config, config):
        raise BadInput(
            f"train.warm_from {run}",
            f"run {found.run_key[:12]}'s networks are not this run's (objective "
            f"{found.objective!r}, or other sizes)",
        )
    return found


def tracker_run(con: duckdb.DuckDBPyConnection, run_key: str) -> RunInfo:
    """The finished tracker run ``run_key``."""
    (found,) = finished_runs(con, "p.key = ?", [run_key])
    return found


def dataset_tracker(
    con: duckdb.DuckDBPyConnection, dataset_key: str, named: str = "", setting: str = ""
) -> RunInfo | None:
    """The newest finished tracker run (train.objective 'track') on dataset ``dataset_key``:
    the one evaluation replays the held-out clips with and a MAAIP run distils
    (`train.distill.from_tracker`); None if there is none. With ``named`` (a key prefix, given
    by ``setting``), that run: BadInput when it is not a tracker run on the dataset."""
    if named:
        found = finished_run(con, named, setting)
        if found.objective != "track" or found.dataset_key != dataset_key:
            raise BadInput(
                f"{setting} {named}",
                f"is not a tracker run on dataset {dataset_key[:12]} (its objective is "
                f"{found.objective!r}, its dataset {found.dataset_key[:12]})",
            )
        return found
    runs = finished_runs(con, "p.video_id = ?", [dataset_key])
    found = [r for r in runs if r.objective == "track"]
    return found[-1] if found else None


def _fits(settings: dict, config: TrainConfig) -> bool:
    """Whether a run made with ``settings`` (its stored `train` config) has networks of
    ``config``'s shapes (a tracker's and MAAIP's policies see different observations)."""
    try:
        theirs = build(TrainConfig, settings, section="train")
    except (ValueError, TypeError):  # settings of an older version that no longer exist
        return False
    # A tracker made before `value_sees_partner` existed had a value that saw the partner.
    sees_partner = (settings.get("track") or {}).get("value_sees_partner", True)
    return (
        theirs.objective == config.objective
        and theirs.network.hidden_sizes == config.network.hidden_sizes
        and theirs.reward.task_observation_dim == config.reward.task_observation_dim
        and (config.objective != "track" or sees_partner == config.track.value_sees_partner)
    )


def warm_start_source(
    con: duckdb.DuckDBPyConnection, dataset_key: str, config: TrainConfig
) -> RunInfo | None:
    """The run a new run on dataset ``dataset_key`` starts from (`TrainConfig.warm_start`): the
    newest finished run on a dataset of the same adversary assembled before this one, whose
    humanoids (`training_bones`) and network sizes are this run's; None if there is none or
    warm starts are off. Only earlier datasets count, so that the choice (part of the run's key)
    stays the same when the run is asked for again."""
    if not config.warm_start:
        return None
    earlier = (
        "p.video_id IN (SELECT theirs.dataset_key FROM datasets theirs JOIN datasets ours "
        "ON ours.dataset_key = ? WHERE theirs.adversary = ours.adversary "
        "AND theirs.created_at < ours.created_at)"
    )
    bones = training_bones(con, dataset_key)
    for found in reversed(finished_runs(con, earlier, [dataset_key])):  # the newest first
        if _fits(found.config, config) and training_bones(con, found.dataset_key) == bones:
            return found
    return None


CURVES = (
    "episode_length_s",
    "falls_per_min",
    "reward_motion",
    "reward_interaction",
    "reward_total",
    "motion_accuracy_fake",
    "interaction0_accuracy_fake",
    "body_error_cm",  # a tracker's (train.objective 'track')
    "root_error_cm",
)


def learning_curves(
    con: duckdb.DuckDBPyConnection, key: str, *, every: int = 100, names=CURVES
) -> list[dict]:
    """Means of the run's per-iteration metrics over blocks of ``every`` iterations, one row per
    block: {"iterations": "0-99", name: mean, ...} (the newest block names only the iterations
    it holds). ``key`` may be a prefix of the run key."""
    found = con.execute(
        "SELECT DISTINCT key FROM train_iterations WHERE key LIKE ? || '%'", [key]
    ).fetchall()
    if len(found) != 1:
        problem = "matches no training run" if not found else "matches several runs"
        raise BadInput(f"--run {key}", f"{problem}; see `ringside metrics --stage train`")
    rows = con.execute(
        "SELECT iteration // ? AS block, name, avg(value) FROM train_iterations "
        "WHERE key = ? AND list_contains(?, name) GROUP BY ALL ORDER BY ALL",
        [every, found[0][0], list(names)],
    ).fetchall()
    # The iterations each block holds: the newest may not be full yet.
    spans = con.execute(
        "SELECT iteration // ? AS block, min(iteration), max(iteration) FROM train_iterations "
        "WHERE key = ? GROUP BY ALL",
        [every, found[0][0]],
    ).fetchall()
    held = {block: f"{first}-{last}" for block, first, last in spans}
    blocks: dict[int, dict] = {}
    for block, name, value in rows:
        blocks.setdefault(block, {"iterations": held[block]})[name] = value
    return list(blocks.values())


def newest_checkpoint(
    con: duckdb.DuckDBPyConnection, key: str, dataset_key: str
) -> tuple[int, str] | None:
    """(iteration, artifact) of run ``key``'s newest checkpoint on ``dataset_key``, if any."""
    row = con.execute(
        "SELECT iteration, artifact FROM train_checkpoints WHERE key = ? AND video_id = ? "
        "ORDER BY iteration DESC LIMIT 1",
        [key, dataset_key],
    ).fetchone()
    return None if row is None else (row[0], row[1])


def record_checkpoint(
    con: duckdb.DuckDBPyConnection,
    key: str,
    dataset_key: str,
    iteration: int,
    artifact: str,
    metrics: Columns,
) -> list[str]:
    """Record checkpoint ``artifact`` at ``iteration`` with the per-iteration ``metrics``
    (columns iteration, name, value) since the last one, and forget the run's older
    checkpoints; the artifacts of those that nothing refers to any more (to delete). Run it in
    a transaction."""
    insert_columns(con, "train_iterations", key, dataset_key, metrics)
    # A DELETE and an INSERT, not INSERT OR REPLACE: a lake's tables have no primary key.
    con.execute(
        "DELETE FROM train_checkpoints WHERE key = ? AND video_id = ? AND iteration = ?",
        [key, dataset_key, iteration],
    )
    con.execute(
        "INSERT INTO train_checkpoints VALUES (?, ?, ?, ?, ?)",
        [key, dataset_key, iteration, artifact, utcnow()],
    )
    old = con.execute(
        "DELETE FROM train_checkpoints WHERE key = ? AND video_id = ? AND iteration < ? "
        "RETURNING artifact",
        [key, dataset_key, iteration],
    ).fetchall()
    kept = {
        row[0]
        for row in con.execute(
            "SELECT artifact FROM train_checkpoints UNION SELECT artifact FROM train_policies"
        ).fetchall()
    }
    return [artifact for (artifact,) in old if artifact not in kept]


def drop_iterations(con: duckdb.DuckDBPyConnection, key: str, dataset_key: str, *, since: int):
    """Forget run ``key``'s metrics from iteration ``since`` on (a resumed run recomputes them)."""
    con.execute(
        "DELETE FROM train_iterations WHERE key = ? AND video_id = ? AND iteration >= ?",
        [key, dataset_key, since],
    )


def metric_series(
    con: duckdb.DuckDBPyConnection, key: str, dataset_key: str, name: str
) -> list[float]:
    """Run ``key``'s per-iteration metric ``name``, oldest iteration first, where recorded."""
    return [
        value
        for (value,) in con.execute(
            "SELECT value FROM train_iterations WHERE key = ? AND video_id = ? AND name = ? "
            "ORDER BY iteration",
            [key, dataset_key, name],
        ).fetchall()
    ]


GATE_METRICS = (
    "gate_finished_pct",
    "gate_body_error_cm",
    "gate_root_error_cm",
    "gate_met",
    "gate_held",
)


def gate_checks(con: duckdb.DuckDBPyConnection, key: str) -> list[dict[str, Any]]:
    """Tracker run ``key``'s gate checks, oldest first: the number of iterations done when each
    was made, its figures and whether the gate was met and held then (`GATE_METRICS`)."""
    rows = con.execute(
        "SELECT iteration + 1, name, value FROM train_iterations WHERE key = ? AND name IN "
        f"({', '.join('?' for _ in GATE_METRICS)}) ORDER BY iteration, name",
        [key, *GATE_METRICS],
    ).fetchall()
    checks: dict[int, dict[str, Any]] = {}
    for iteration, name, value in rows:
        checks.setdefault(iteration, {"iterations": iteration})[name] = value
    return list(checks.values())


def iteration_means(
    con: duckdb.DuckDBPyConnection,
    key: str,
    dataset_key: str,
    *,
    since: int,
    until: int | None = None,
) -> dict[str, float]:
    """Each per-iteration metric of run ``key``, averaged from iteration ``since`` on (to
    ``until``, inclusive, if given)."""
    last = "" if until is None else " AND iteration <= ?"
    return dict(
        con.execute(
            "SELECT name, avg(value) FROM train_iterations WHERE key = ? AND video_id = ? "
            f"AND iteration >= ?{last} GROUP BY name",
            [key, dataset_key, since, *([] if until is None else [until])],
        ).fetchall()
    )


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


def dataset_tracking(con: duckdb.DuckDBPyConnection, dataset_key: str) -> tuple[str, list[dict]]:
    """The newest finished tracker run on dataset ``dataset_key`` and its ``train_tracking``
    rows (split, agent, clip, finished, frames, body_error_cm, root_error_cm; held-out clips
    first, then by error, worst first): each clip's tracking error, a measure of how well a
    physics body can follow that footage. ('', []) when there is none."""
    found = con.execute(
        "SELECT t.key FROM train_tracking t JOIN stage_outputs o ON o.stage = 'train' "
        "AND o.key = t.key AND o.video_id = t.video_id WHERE t.video_id = ? "
        "ORDER BY o.created_at DESC, t.key LIMIT 1",
        [dataset_key],
    ).fetchone()
    if found is None:
        return "", []
    cursor = con.execute(
        "SELECT split, agent, clip, finished, frames, body_error_cm, root_error_cm "
        "FROM train_tracking WHERE key = ? AND video_id = ? "
        "ORDER BY split = 'train', body_error_cm DESC, agent, clip",
        [found[0], dataset_key],
    )
    names = [d[0] for d in cursor.description]
    return found[0], [dict(zip(names, row, strict=True)) for row in cursor.fetchall()]


def clips_finished(
    con: duckdb.DuckDBPyConnection, run_key: str, split: str, agent: int
) -> dict[str, bool]:
    """Whether tracker run ``run_key``, once trained, finished each clip of ``split`` it tracked
    as ``agent`` (`train_tracking`), by clip name."""
    rows = con.execute(
        "SELECT clip, finished FROM train_tracking WHERE key = ? AND split = ? AND agent = ?",
        [run_key, split, agent],
    ).fetchall()
    return dict(rows)
