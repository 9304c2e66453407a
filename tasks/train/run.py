"""A training run as the train stage does it: resume, iterate, record, checkpoint, commit.

Every `checkpoint_every` iterations the trainer's state goes to the artifact store and, in
one transaction, its row to `train_checkpoints` and the metrics of the iterations since the
last checkpoint to `train_iterations`; the run's older checkpoint is then deleted (a checkpoint
holds the full replay buffers, about 590 MB with the defaults, so keeping each one filled the
disk). A run killed midway, started again with the same key, continues from its checkpoint:
the table always reads as one uninterrupted run, and the iterations the kill lost are
recomputed as they would have been. Writing metrics per checkpoint rather than per iteration
also saves a DuckDB connection per iteration (measured: about a quarter of an iteration's
time with the cpu preset).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from models.maaip.trainer import Trainer, checkpoint_policy
from models.tracking.gate import gate_held, gate_met, track_gate
from storage.artifacts import artifact_path, put_bytes, read_bytes
from storage.db import connect, transact
from tasks.config import build
from tasks.dataset.demonstrations import load_demonstrations
from tasks.runner import StageOutput
from tasks.train.config import TrainConfig
from tasks.train.store import (
    PolicyRow,
    RunInfo,
    drop_iterations,
    iteration_means,
    metric_series,
    newest_checkpoint,
    record_checkpoint,
)
from tasks.train.tracker import clip_tracking, footage_tracking, with_streams

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
    "body_error_cm",
    "root_error_cm",
)
SUMMARY_WINDOW = 10


def _save(
    db: Path,
    artifacts: Path,
    key: str,
    dataset_key: str,
    trainer: Trainer,
    pending: list[tuple[int, dict]],
) -> str:
    """Checkpoint the trainer with the metrics of the iterations since the last checkpoint,
    then delete the run's older checkpoints; the new checkpoint's artifact name."""
    name = put_bytes(artifacts, trainer.checkpoint(), ".pt")
    metrics = {
        "iteration": np.array([i for i, metrics in pending for _ in metrics], dtype=np.int64),
        "name": np.array([n for _, metrics in pending for n in metrics], dtype=object),
        "value": np.array([float(v) for _, metrics in pending for v in metrics.values()]),
    }
    with connect(db) as con:
        unused = transact(
            con, lambda c: record_checkpoint(c, key, dataset_key, trainer.iteration, name, metrics)
        )
    for artifact in unused:
        artifact_path(artifacts, artifact).unlink(missing_ok=True)
    return name


def _distil(
    db: Path, artifacts: Path, dataset_key: str, trainer: Trainer, teacher: RunInfo
) -> dict[str, float]:
    """Distil tracker run ``teacher`` into ``trainer``'s policy on the dataset's train clips;
    each round's figures as metrics ``distill_<name>_<round>``."""
    with connect(db, read_only=True) as con:
        found = footage_tracking(
            con, dataset_key, fps=trainer.config.env.policy_hz, splits=("train",)
        )
    config = build(TrainConfig, teacher.config, section="train")
    policy, _ = checkpoint_policy(read_bytes(artifacts, teacher.artifact), config)
    rounds = trainer.distill_from(policy, found["train"])
    return {
        f"distill_{name}_{int(r['round'])}": value
        for r in rounds
        for name, value in r.items()
        if name != "round"
    }


def train(
    *,
    db: Path,
    artifacts: Path,
    dataset_key: str,
    key: str,
    config: TrainConfig,
    warm: RunInfo | None = None,
    teacher: RunInfo | None = None,
    stop: Callable[[int], bool] | None = None,
) -> StageOutput:
    """Train (or go on training) run ``key`` on dataset ``dataset_key``; its stage output.

    A tracker (objective 'track') trains on the dataset's footage clips and, once trained,
    tracks every clip of both splits: its ``train_tracking`` rows and ``track_*`` metrics
    (`tasks.train.tracker`).

    A run with no checkpoint of its own starts from ``warm``'s networks when given
    (`tasks.train.store.warm_start_source`), or from tracker run ``teacher`` distilled into its
    policy (`Trainer.distill_from`; the rounds' figures are iteration 0's ``distill_*``
    metrics). ``stop(iteration)`` may end the run early, as a
    kill would (raising KeyboardInterrupt, nothing saved beyond the last checkpoint); tests use
    it.
    """
    with connect(db, read_only=True) as con:
        tracking = (
            footage_tracking(con, dataset_key, fps=config.env.policy_hz)
            if config.objective == "track"
            else None
        )
        data = (
            load_demonstrations(con, dataset_key)
            if tracking is None
            else with_streams(tracking["train"], config)
        )
    trainer = Trainer(config, data)
    notes = []
    try:
        with connect(db, read_only=True) as con:
            found = newest_checkpoint(con, key, dataset_key)
        if found is None and warm is not None:
            trainer.warm_start(read_bytes(artifacts, warm.artifact))
        if warm is not None:
            notes.append(
                f"started from the networks of run {warm.run_key[:12]} (iteration "
                f"{warm.iteration}, dataset {warm.dataset_key[:12]})"
            )
        distilled: dict[str, float] = {}
        if found is None and teacher is not None:
            distilled = _distil(db, artifacts, dataset_key, trainer, teacher)
            notes.append(
                f"started from tracker run {teacher.run_key[:12]} distilled into the policy "
                f"({config.distill.rounds} rounds)"
            )
        if found is not None:
            trainer.restore(read_bytes(artifacts, found[1]))
            with connect(db) as con:
                transact(
                    con, lambda c: drop_iterations(c, key, dataset_key, since=trainer.iteration)
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
        deadline = start + config.minutes * 60 if config.minutes > 0 else math.inf
        pending: list[tuple[int, dict]] = []
        final = None
        gates = tracking is not None and config.track.gate_every > 0
        met: list[float] = []
        if gates:
            with connect(db, read_only=True) as con:
                met = metric_series(con, key, dataset_key, "gate_met")
        held = gates and gate_held(met, config.track)
        while trainer.iteration < total and not (held and config.track.stop_when_held):
            iteration = trainer.iteration
            metrics = {**trainer.iterate(), **distilled}
            distilled = {}
            if gates and trainer.iteration % config.track.gate_every == 0:
                assert tracking is not None
                checked = track_gate(trainer.nets.policy, tracking["train"], config)
                met.append(float(gate_met(checked, config.track)))
                held = gate_held(met, config.track)
                metrics |= {
                    "gate_finished_pct": checked.finished_pct,
                    "gate_body_error_cm": checked.body_error_cm,
                    "gate_root_error_cm": checked.root_error_cm,
                    "gate_met": met[-1],
                    "gate_held": float(held),
                }
            pending.append((iteration, metrics))
            bar.update(1)
            if "episode_length_s" in metrics:
                bar.set_postfix(ep_s=f"{metrics['episode_length_s']:.2f}")
            stop_held = held and config.track.stop_when_held
            if trainer.iteration % config.checkpoint_every == 0 or stop_held:
                final = _save(db, artifacts, key, dataset_key, trainer, pending)
                pending = []
                if time.perf_counter() >= deadline or stop_held:
                    break
            if stop is not None and stop(trainer.iteration):
                raise KeyboardInterrupt(f"stopped at iteration {trainer.iteration}")
        bar.close()
        if pending or final is None:
            final = _save(db, artifacts, key, dataset_key, trainer, pending)
        total = trainer.iteration
        rows: dict = {}
        judged: dict[str, float] = {}
        if tracking is not None:
            rows["train_tracking"], judged = clip_tracking(trainer.nets.policy, tracking, config)
            if gates:
                window = met[-config.track.gate_window :]
                judged["track_gate_held"] = float(held)
                judged["track_gate_checks"] = float(len(met))
                judged["track_gate_met_of_last"] = float(sum(window))
    finally:
        trainer.close()
    with connect(db, read_only=True) as con:
        means = iteration_means(con, key, dataset_key, since=max(0, total - SUMMARY_WINDOW))
        first = iteration_means(con, key, dataset_key, since=0, until=0)
    summary = {name: value for name, value in means.items() if name in SUMMARY}
    summary |= {name: value for name, value in first.items() if name.startswith("distill_")}
    summary["iterations"] = float(total)
    summary["train_minutes_this_session"] = (time.perf_counter() - start) / 60
    return StageOutput(
        rows={"train_policies": [PolicyRow(total, final)], **rows},
        metrics={**summary, **judged},
        notes=tuple(notes),
    )
