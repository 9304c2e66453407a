"""Prefect task of the lift stage, and reading the pose output it starts from."""

from __future__ import annotations

from pathlib import Path

from tqdm import tqdm

from storage.paths import data_paths
from tasks.ingest.store import IngestOutput
from tasks.lift.config import LiftStageConfig
from tasks.lift.stage import (
    STAGE,
    fighter_tracks,
    lift_code,
    lift_upstream,
    lift_video,
)
from tasks.pose.store import fighter_keypoints
from tasks.runner import StageCall


def lift_call(
    data_root: str,
    ingest: IngestOutput,
    pose_key: str,
    config: LiftStageConfig,
    key: str,
    calibration_sha: str | None,
) -> StageCall:
    """Lift both fighters of a video and commit the output under ``key``."""
    from storage.db import connect

    paths = data_paths(data_root)

    def compute():
        with connect(paths.db, read_only=True) as con:
            fighters = fighter_tracks(
                fighter_keypoints(con, ingest.video_id, pose_key), ingest.frames
            )
        # Shown on an interactive terminal only, as pose's.
        with tqdm(
            total=ingest.frames, unit="frame", desc=f"lift {Path(ingest.path).name}", disable=None
        ) as bar:
            return lift_video(
                fighters,
                key=key,
                video_id=ingest.video_id,
                fps=ingest.fps,
                size=(ingest.width, ingest.height),
                shots=list(ingest.shots),
                config=config,
                calibration=Path(config.calibration) if config.calibration else None,
                artifacts=paths.artifacts,
                progress=bar.update,
            )

    return StageCall(
        run_name=f"lift-{ingest.video_id:.12}",
        stage=STAGE,
        video_id=ingest.video_id,
        key=key,
        config=config,
        code=lift_code(),
        upstream=lift_upstream(pose_key, calibration_sha),
        compute=compute,
    )
