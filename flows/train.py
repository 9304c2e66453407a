"""The train stage as a flow: MAAIP on one assembled dataset."""

from __future__ import annotations

from pathlib import Path

from prefect import flow

from flows.config import from_tables
from flows.runs import StageSummary, reuse_or_run
from storage.db import connect
from storage.paths import data_paths
from tasks.dataset.store import DatasetInfo, UnknownDataset, dataset_info
from tasks.errors import BadInput
from tasks.runner import StageCall
from tasks.train.run import STAGE
from tasks.train.store import warm_start_source
from tasks.train.task import train_call, train_key


def resolve_dataset(data_root: str | Path, dataset_key: str) -> DatasetInfo:
    """The dataset ``dataset_key`` (or a prefix of its key) names; BadInput naming what is
    wrong when there is none."""
    db = data_paths(data_root).db
    if not db.exists():
        raise BadInput(str(db), "no database yet: process some footage first")
    with connect(db) as con:  # writable: brings an older database's schema up to date
        try:
            return dataset_info(con, dataset_key)
        except UnknownDataset as error:
            raise BadInput(f"--dataset {dataset_key}", str(error)) from None


@flow(name="train", flow_run_name="train-{dataset_key:.12}")
def train_flow(
    data_root: str, dataset_key: str, config: dict | None = None, force: bool = False
) -> StageSummary:
    """Train the two fighters' policies on dataset ``dataset_key`` (`ringside datasets`; a
    prefix of a key will do).

    The settings and the dataset are checked before anything is computed. A new run starts
    from the networks of the adversary's previous run where `train.warm_start` finds one
    (`warm_start_source`).
    """
    settings = from_tables(config or {}).train
    info = resolve_dataset(data_root, dataset_key)
    with connect(data_paths(data_root).db) as con:
        warm = warm_start_source(con, info.dataset_key, settings)
    dataset_key = info.dataset_key  # the whole key, where a prefix was given
    key = train_key(settings, dataset_key, warm)

    def call() -> StageCall:
        return train_call(data_root, dataset_key, settings, key, warm)

    result, state = reuse_or_run(
        data_root, stage=STAGE, video_id=dataset_key, key=key, force=force, call=call
    )
    return StageSummary(
        dataset_key, info.adversary, STAGE, key, state, result.seconds, result.notes
    )
