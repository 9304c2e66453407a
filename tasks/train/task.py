"""The train stage's plan: MAAIP (or a tracker, `train.objective`) on one assembled dataset."""

from __future__ import annotations

from pathlib import Path

import duckdb

from storage.db import connect
from storage.keys import code_version
from storage.paths import DataPaths
from tasks.dataset.store import DatasetInfo, UnknownDataset, dataset_info
from tasks.errors import BadInput
from tasks.runner import StagePlan, StageSpec
from tasks.stage_inputs import NoInputs
from tasks.train.config import TrainConfig
from tasks.train.run import STAGE, train
from tasks.train.store import RunInfo, dataset_tracker, named_warm_start, warm_start_source


def train_code() -> str:
    return code_version(
        "tasks.train",
        "tasks.dataset",
        "tasks.deepmimic",
        "models.humanoid",
        "models.arena",
        "models.maaip",
        "models.tracking",
    )


def train_spec(
    config: TrainConfig,
    dataset_key: str,
    warm: RunInfo | None = None,
    teacher: RunInfo | None = None,
) -> StageSpec:
    """The run on ``dataset_key``; its upstream names the run whose networks a warm start
    takes, or the tracker run it distils, if any."""
    upstream = {"dataset": dataset_key}
    if warm is not None:
        upstream["warm_start"] = warm.run_key
    if teacher is not None:
        upstream["tracker"] = teacher.run_key
    return StageSpec(STAGE, dataset_key, config, train_code(), upstream)


def distilled_tracker(
    con: duckdb.DuckDBPyConnection, dataset_key: str, config: TrainConfig
) -> RunInfo | None:
    """The tracker run a MAAIP run with `train.distill.from_tracker` distils: the dataset's
    newest (`dataset_tracker`); None when the setting is off. BadInput, in one line, when it is
    on and the dataset has no tracker."""
    if not config.distill.from_tracker:
        return None
    found = dataset_tracker(con, dataset_key)
    if found is None:
        raise BadInput(
            "train.distill.from_tracker",
            f"no finished tracker run on dataset {dataset_key[:12]}: `ringside train --dataset "
            f"{dataset_key[:12]} --train-objective track` trains one first",
        )
    return found


def resolve_dataset(db: Path, dataset_key: str) -> DatasetInfo:
    """The dataset ``dataset_key`` (or a prefix of its key) names; BadInput naming what is
    wrong when there is none."""
    if not db.exists():
        raise BadInput(str(db), "no database yet: process some footage first")
    with connect(db) as con:  # writable: brings an older database's schema up to date
        try:
            return dataset_info(con, dataset_key)
        except UnknownDataset as error:
            raise BadInput(f"--dataset {dataset_key}", str(error)) from None


def train_plan(
    paths: DataPaths, config: TrainConfig, dataset_key: str, inputs: NoInputs
) -> StagePlan:
    """Train the two fighters' policies on dataset ``dataset_key`` (a prefix of a key will
    do), resuming from the run's newest checkpoint, or starting from the networks of run
    `train.warm_from`, or else of the adversary's previous run where `train.warm_start` finds one
    (`warm_start_source`)."""
    info = resolve_dataset(paths.db, dataset_key)
    with connect(paths.db) as con:
        teacher = distilled_tracker(con, info.dataset_key, config)
        if teacher and config.warm_from:
            raise BadInput(
                "train.warm_from",
                "a run distilled from a tracker (train.distill.from_tracker) starts from it",
            )
        # A distilled run starts from the tracker, not from an earlier run's networks.
        if config.warm_from:
            warm = named_warm_start(con, config.warm_from, config)
        else:
            warm = None if teacher else warm_start_source(con, info.dataset_key, config)
    spec = train_spec(config, info.dataset_key, warm, teacher)
    return StagePlan(
        spec,
        info.adversary,
        compute=lambda: train(
            db=paths.db,
            artifacts=paths.artifacts,
            dataset_key=info.dataset_key,
            key=spec.key,
            config=config,
            warm=warm,
            teacher=teacher,
        ),
    )
