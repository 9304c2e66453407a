"""What the train stage reads from the database before it trains: the run to warm-start from."""

from __future__ import annotations

import json
from dataclasses import dataclass

import duckdb

from models.maaip.config import TrainConfig
from tasks.config import build
from tasks.dataset.store import training_bones


@dataclass(frozen=True)
class WarmStart:
    """A finished run whose networks a new run starts from."""

    run_key: str
    dataset_key: str
    iteration: int
    artifact: str  # its final checkpoint


def _fits(stored: str, config: TrainConfig) -> bool:
    """Whether a run made with settings ``stored`` (JSON) has networks of ``config``'s shapes."""
    try:
        theirs = build(TrainConfig, json.loads(stored), section="train")
    except (ValueError, TypeError):  # settings of an older version that no longer exist
        return False
    return (
        theirs.network.hidden_sizes == config.network.hidden_sizes
        and theirs.reward.task_observation_dim == config.reward.task_observation_dim
    )


def warm_start_source(
    con: duckdb.DuckDBPyConnection, dataset_key: str, config: TrainConfig
) -> WarmStart | None:
    """The run a new run on dataset ``dataset_key`` starts from (`TrainConfig.warm_start`): the
    newest finished run on a dataset of the same adversary assembled before this one, whose
    humanoids (`training_bones`) and network sizes are this run's; None if there is none or
    warm starts are off. Only earlier datasets count, so that the choice (part of the run's key)
    stays the same when the run is asked for again."""
    if not config.warm_start:
        return None
    rows = con.execute(
        """
        SELECT p.key, p.video_id, p.iteration, p.artifact, o.config
        FROM train_policies p
        JOIN stage_outputs o ON o.stage = 'train' AND o.key = p.key AND o.video_id = p.video_id
        JOIN datasets theirs ON theirs.dataset_key = p.video_id
        JOIN datasets ours ON ours.dataset_key = ?
        WHERE theirs.adversary = ours.adversary AND theirs.created_at < ours.created_at
        ORDER BY o.created_at DESC, p.key
        """,
        [dataset_key],
    ).fetchall()
    bones = training_bones(con, dataset_key)
    for run_key, their_dataset, iteration, artifact, stored in rows:
        if _fits(stored, config) and training_bones(con, their_dataset) == bones:
            return WarmStart(run_key, their_dataset, iteration, artifact)
    return None
