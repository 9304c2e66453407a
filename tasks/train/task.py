"""Prefect task of the train stage."""

from __future__ import annotations

from models.maaip.config import TrainConfig
from storage.keys import code_version, stage_key
from storage.paths import data_paths
from tasks.runner import StageCall
from tasks.train.run import STAGE, train
from tasks.train.store import WarmStart


def train_code() -> str:
    return code_version("tasks.train", "tasks.dataset", "models.humanoid", "models.maaip")


def train_upstream(dataset_key: str, warm: WarmStart | None) -> dict:
    """The dataset and, for a warm start, the run whose networks it starts from."""
    upstream = {"dataset": dataset_key}
    if warm is not None:
        upstream["warm_start"] = warm.run_key
    return upstream


def train_key(config: TrainConfig, dataset_key: str, warm: WarmStart | None = None) -> str:
    return stage_key(STAGE, config, train_code(), train_upstream(dataset_key, warm))


def train_call(
    data_root: str,
    dataset_key: str,
    config: TrainConfig,
    key: str,
    warm: WarmStart | None = None,
) -> StageCall:
    """Train MAAIP on a dataset (resuming from the run's newest checkpoint, or starting from
    ``warm``'s networks) and commit it."""
    paths = data_paths(data_root)
    return StageCall(
        run_name=f"train-{dataset_key:.12}",
        stage=STAGE,
        video_id=dataset_key,
        key=key,
        config=config,
        code=train_code(),
        upstream=train_upstream(dataset_key, warm),
        compute=lambda: train(
            db=paths.db,
            artifacts=paths.artifacts,
            dataset_key=dataset_key,
            key=key,
            config=config,
            warm=warm,
        ),
    )
