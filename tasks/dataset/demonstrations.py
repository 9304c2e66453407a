"""A dataset read as the demonstrations a training run (or an evaluation) learns from."""

from __future__ import annotations

import duckdb
import numpy as np

from models.humanoid.stance import guard_pose
from models.maaip.demonstrations import Demonstrations, ReferenceMotions
from tasks.dataset.store import training_data


def load_demonstrations(con: duckdb.DuckDBPyConnection, dataset_key: str) -> Demonstrations:
    """Dataset ``dataset_key``'s demonstrations (`tasks.dataset.store.training_data`), with
    each fighter's guard (`guard_pose`) from its episode-start frames.

    Raises:
        UnknownDataset: no such dataset.
        BadInput: the dataset has no interaction clip to learn from or start episodes in.
    """
    data = training_data(con, dataset_key)
    (q0, q1), (v0, v1) = data.qpos, data.qvel
    return Demonstrations(
        dataset_key=dataset_key,
        motion=data.motion,
        interaction=data.interaction,
        reference=ReferenceMotions(
            qpos0=q0,
            qvel0=v0,
            qpos1=q1,
            qvel1=v1,
            stance=np.stack([guard_pose(data.bones[0], q0), guard_pose(data.bones[1], q1)]),
        ),
        bones=data.bones,
        held_out=data.held_out,
    )
