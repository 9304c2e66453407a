"""The lift stage as a flow: both fighters of a video to humanoid motions in one world."""

from __future__ import annotations

from pathlib import Path

from prefect import flow
from prefect.runtime import flow_run

from flows.config import from_tables
from flows.runs import StageSummary, reuse_or_run
from storage.db import connect
from storage.files import sha256_file
from storage.paths import data_paths
from tasks.errors import BadInput
from tasks.ingest.store import load_ingest
from tasks.lift.stage import STAGE, lift_key
from tasks.lift.task import lift_call
from tasks.runner import StageCall


def _run_name() -> str:
    return f"lift-{flow_run.parameters['video_id'][:12]}"


@flow(name="lift", flow_run_name=_run_name)
def lift_flow(
    data_root: str,
    video_id: str,
    ingest_key: str,
    pose_key: str,
    config: dict | None = None,
    force: bool = False,
) -> StageSummary:
    """Lift both fighters of an ingested, posed video to 3D and clean them up in MuJoCo."""
    settings = from_tables(config or {}).lift
    paths = data_paths(data_root)
    with connect(paths.db, read_only=True) as con:
        ingest = load_ingest(con, video_id, ingest_key)
    calibration_sha = None
    if settings.calibration:
        calibration = Path(settings.calibration)
        if not calibration.is_file():
            raise BadInput(str(calibration), "calibration file not found (lift.calibration)")
        calibration_sha = sha256_file(calibration)
    key = lift_key(settings, pose_key, calibration_sha)

    def call() -> StageCall:
        return lift_call(data_root, ingest, pose_key, settings, key, calibration_sha)

    result, state = reuse_or_run(
        data_root, stage=STAGE, video_id=video_id, key=key, force=force, call=call
    )
    return StageSummary(video_id, ingest.path, STAGE, key, state, result.seconds, result.notes)
