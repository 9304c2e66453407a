"""The lift stage's plan: both fighters of a posed video to humanoid motions in one world."""

from __future__ import annotations

from pathlib import Path

from tqdm import tqdm

from storage.db import connect
from storage.files import sha256_file
from storage.paths import DataPaths
from tasks.errors import BadInput
from tasks.ingest.store import load_ingest
from tasks.lift.config import LiftStageConfig
from tasks.lift.stage import fighter_tracks, lift_output, lift_spec, lift_video
from tasks.pose.store import fighter_keypoints
from tasks.runner import StagePlan
from tasks.stage_inputs import LiftInputs


def lift_plan(
    paths: DataPaths, config: LiftStageConfig, video_id: str, inputs: LiftInputs
) -> StagePlan:
    """Lift both fighters of pose output ``inputs.pose`` to 3D and clean them up in MuJoCo
    (with the calibration, when one is set, whose bytes are then part of the key)."""
    with connect(paths.db, read_only=True) as con:
        ingest = load_ingest(con, video_id, inputs.ingest)
    calibration = Path(config.calibration) if config.calibration else None
    calibration_sha = None
    if calibration is not None:
        if not calibration.is_file():
            raise BadInput(str(calibration), "calibration file not found (lift.calibration)")
        calibration_sha = sha256_file(calibration)
    pose_key = inputs.pose
    spec = lift_spec(config, video_id, pose_key, calibration_sha)

    def compute():
        with connect(paths.db, read_only=True) as con:
            fighters = fighter_tracks(fighter_keypoints(con, video_id, pose_key), ingest.frames)
        # Shown on an interactive terminal only, as pose's.
        with tqdm(
            total=ingest.frames, unit="frame", desc=f"lift {Path(ingest.path).name}", disable=None
        ) as bar:
            lift = lift_video(
                fighters,
                fps=ingest.fps,
                size=(ingest.width, ingest.height),
                shots=list(ingest.shots),
                config=config,
                calibration=calibration,
                progress=bar.update,
            )
        return lift_output(lift)

    return StagePlan(spec, ingest.path, compute)
