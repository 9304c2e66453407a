"""The train stage's plan: MAAIP (or a tracker, `train.objective`) on one assembled dataset."""

from __future__ import annotations

from pathlib import Path

from models.maaip.config import TrainConfig
from storage.db import connect
from storage.keys import code_version
from storage.paths import DataPaths
from tasks.dataset.store import DatasetInfo, UnknownDataset, dataset_info
from tasks.errors import BadInput
from tasks.registry import NoInputs
from tasks.runner import StagePlan, StageSpec
from tasks.train.run import STAGE, train
from tasks.train.store import WarmStart, warm_start_source


def train_code() -> str:
    return code_version(
        "tasks.train", "tasks.dataset", "tasks.deepmimic", "models.humanoid", "models.maaip"
    )


def train_spec(config: TrainConfig, dataset_key: str, warm: WarmStart | None = None) -> StageSpec:
    """The run on ``dataset_key``; its upstream names the run whose networks a warm start
    takes, if any."""
    upstream = {"dataset": dataset_key}
    if warm is not None:
        upstream["warm_start"] = warm.run_key
    return StageSpec(STAGE, dataset_key, config, train_code(), upstream)


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
    do), resuming from the run's newest checkpoint, or starting from the networks of the
    adversary's previous run where `train.warm_start` finds one (`warm_start_source`)."""
    info = resolve_dataset(paths.db, dataset_key)
    with connect(paths.db) as con:
        warm = warm_start_source(con, info.dataset_key, config)
    spec = train_spec(config, info.dataset_key, warm)
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
        ),
    )
