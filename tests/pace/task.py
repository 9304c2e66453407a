"""The pace stage's plan: the lifted pelvis's speed of each fighter."""

from dataclasses import dataclass

import numpy as np

from models.humanoid.motion import RATE
from pace import PaceInputs
from pace.config import PaceConfig
from storage.db import connect
from storage.keys import code_version
from storage.paths import DataPaths
from tasks.lift.store import load_motion
from tasks.runner import StageOutput, StagePlan, StageSpec


@dataclass(frozen=True)
class SpeedRow:
    """A ``pace_speeds`` row."""

    role: str
    speed_m_s: float


def pace_plan(paths: DataPaths, config: PaceConfig, video_id: str, inputs: PaceInputs) -> StagePlan:
    lift_key = inputs.lift
    spec = StageSpec("pace", video_id, config, code_version("pace"), {"lift": lift_key})

    def compute() -> StageOutput:
        with connect(paths.db, read_only=True) as con:
            motion = load_motion(con, video_id, lift_key)
        rows, metrics = [], {}
        for role, fighter in motion.items():
            # Between consecutive steps only: none is taken across a gap or a cut.
            next_step = np.diff(fighter.step) == 1
            moved = np.diff(fighter.qpos[:, :2], axis=0)[next_step]
            speed = np.linalg.norm(moved, axis=1) * RATE
            value = float(np.percentile(speed, config.percentile))
            rows.append(SpeedRow(role, value))
            metrics[f"{role}_speed_m_s"] = value
        return StageOutput({"pace_speeds": rows}, metrics)

    return StagePlan(spec, video_id, compute)
