"""A training run as the train stage does it: resume, iterate, record, checkpoint, commit.

Per-iteration metrics go to `train_iterations` as they are made, checkpoints to the artifact
store every `checkpoint_every` iterations (`train_checkpoints`). A run killed midway, started
again with the same key, continues from its newest checkpoint; the metric rows after that
checkpoint are dropped first, so the table always reads as one uninterrupted run.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path

import duckdb
from tqdm import tqdm

from storage.artifacts import put_bytes, read_bytes
from storage.db import connect, transaction, utcnow
from tasks.errors import BadInput
from tasks.runner import StageOutput
from tasks.train.config import TrainConfig
from tasks.train.data import load_demonstrations
from tasks.train.mappo import Trainer

STAGE = "train"

# What the stage reports of the whole run: the means over its last iterations of these.
SUMMARY = (
    "episode_length_s",
    "falls_per_min",
    "reward_motion",
    "reward_interaction",
    "reward_total",
    "damage_received_n",
    "env_steps_per_s",
)
SUMMARY_WINDOW = 10


CURVES = (
    "episode_length_s",
    "falls_per_min",
    "reward_motion",
    "reward_interaction",
    "reward_total",
    "motion_accuracy_fake",
    "interaction0_accuracy_fake",
)


def learning_curves(
    con: duckdb.DuckDBPyConnection, key: str, *, every: int = 100, names=CURVES
) -> list[dict]:
    """Means of the run's per-iteration metrics over blocks of ``every`` iterations, one row per
    block: {"iterations": "0-99", name: mean, ...}. ``key`` may be a prefix of the run key."""
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
    blocks: dict[int, dict] = {}
    for block, name, value in rows:
        row = blocks.setdefault(block, {"iterations": f"{block * every}-{(block + 1) * every - 1}"})
        row[name] = value
    return list(blocks.values())


def _newest_checkpoint(db: Path, key: str, dataset_key: str) -> tuple[int, str] | None:
    with connect(db, read_only=True) as con:
        row = con.execute(
            "SELECT iteration, artifact FROM train_checkpoints WHERE key = ? AND video_id = ? "
            "ORDER BY iteration DESC LIMIT 1",
            [key, dataset_key],
        ).fetchone()
    return None if row is None else (row[0], row[1])


def _record(db: Path, key: str, dataset_key: str, iteration: int, metrics: dict) -> None:
    with connect(db) as con:
        con.executemany(
            "INSERT OR REPLACE INTO train_iterations VALUES (?, ?, ?, ?, ?)",
            [[key, dataset_key, iteration, name, float(v)] for name, v in metrics.items()],
        )


def _save(db: Path, artifacts: Path, key: str, dataset_key: str, trainer: Trainer) -> str:
    name = put_bytes(artifacts, trainer.checkpoint(), ".pt")
    with connect(db) as con:
        con.execute(
            "INSERT OR REPLACE INTO train_checkpoints VALUES (?, ?, ?, ?, ?)",
            [key, dataset_key, trainer.iteration, name, utcnow()],
        )
    return name


def train(
    *,
    db: Path,
    artifacts: Path,
    dataset_key: str,
    key: str,
    config: TrainConfig,
    stop: Callable[[int], bool] | None = None,
) -> StageOutput:
    """Train (or go on training) run ``key`` on dataset ``dataset_key``; its stage output.

    ``stop(iteration)`` may end the run early, as a kill would (raising KeyboardInterrupt,
    nothing saved beyond the last checkpoint); tests use it.
    """
    with connect(db, read_only=True) as con:
        demos = load_demonstrations(con, dataset_key)
    trainer = Trainer(config, demos)
    try:
        found = _newest_checkpoint(db, key, dataset_key)
        if found is not None:
            trainer.restore(read_bytes(artifacts, found[1]))
            with connect(db) as con, transaction(con):
                con.execute(
                    "DELETE FROM train_iterations "
                    "WHERE key = ? AND video_id = ? AND iteration >= ?",
                    [key, dataset_key, trainer.iteration],
                )
        total = config.iterations
        bar = tqdm(
            total=total,
            initial=trainer.iteration,
            desc="train",
            unit="it",
            disable=not sys.stderr.isatty(),
        )
        start = time.perf_counter()
        while trainer.iteration < total:
            iteration = trainer.iteration
            metrics = trainer.iterate()
            _record(db, key, dataset_key, iteration, metrics)
            bar.update(1)
            bar.set_postfix(ep_s=f"{metrics['episode_length_s']:.2f}")
            if trainer.iteration % config.checkpoint_every == 0:
                _save(db, artifacts, key, dataset_key, trainer)
            if stop is not None and stop(trainer.iteration):
                raise KeyboardInterrupt(f"stopped at iteration {trainer.iteration}")
        bar.close()
        final = _save(db, artifacts, key, dataset_key, trainer)
    finally:
        trainer.close()
    with connect(db, read_only=True) as con:
        rows = con.execute(
            "SELECT name, avg(value) FROM train_iterations WHERE key = ? AND video_id = ? "
            "AND iteration >= ? GROUP BY name",
            [key, dataset_key, max(0, total - SUMMARY_WINDOW)],
        ).fetchall()
    summary = {name: value for name, value in rows if name in SUMMARY}
    summary["iterations"] = float(total)
    summary["train_minutes_this_session"] = (time.perf_counter() - start) / 60
    return StageOutput(
        rows={"train_policies": [(key, dataset_key, total, final)]},
        metrics=summary,
    )
