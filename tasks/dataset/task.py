"""Prefect tasks of the dataset stage: one video's demonstrations, extra clips, the assembly."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

from prefect import task
from prefect.cache_policies import NO_CACHE

from models.humanoid.boxer import BoneLengths
from storage.db import connect
from storage.paths import data_paths
from tasks.dataset.config import DatasetConfig
from tasks.dataset.stage import (
    STAGE,
    build_dataset,
    dataset_code,
    dataset_upstream,
    extra_clip_output,
)
from tasks.dataset.store import candidate_members, record_dataset
from tasks.errors import BadInput
from tasks.ingest.store import IngestOutput
from tasks.lift.store import load_motion
from tasks.runner import StageCall


def dataset_call(
    data_root: str,
    ingest: IngestOutput,
    lift_key: str,
    config: DatasetConfig,
    key: str,
) -> StageCall:
    """Cut one video's lifted motion into clips, transitions, labels and statistics."""
    paths = data_paths(data_root)

    def compute():
        with connect(paths.db, read_only=True) as con:
            fighters = load_motion(con, ingest.video_id, lift_key)
        if not fighters:
            raise BadInput(STAGE, f"lift output {lift_key} of video {ingest.video_id} is empty")
        return build_dataset(
            fighters,
            key=key,
            video_id=ingest.video_id,
            shots=list(ingest.shots),
            fps=ingest.fps,
            config=config,
        )

    return StageCall(
        run_name=f"dataset-{ingest.video_id:.12}",
        stage=STAGE,
        video_id=ingest.video_id,
        key=key,
        config=config,
        code=dataset_code(),
        upstream=dataset_upstream(lift_key),
        compute=compute,
    )


def extra_clips_call(
    folder: str,
    files: dict[str, str],
    bones: list[BoneLengths],
    video_id: str,
    key: str,
) -> StageCall:
    """The user's extra single-actor clips (``files``: name -> SHA-256), retargeted onto each
    of the fighters' ``bones``, as one dataset output."""
    return StageCall(
        run_name=f"dataset-extra-clips-{video_id:.12}",
        stage=STAGE,
        video_id=video_id,
        key=key,
        config={"extra_clips": folder},
        code=dataset_code(),
        upstream={"files": files, "bones": [asdict(b) for b in bones]},
        compute=lambda: extra_clip_output(Path(folder), bones, key=key, video_id=video_id),
    )


@task(name="dataset-assemble", cache_policy=NO_CACHE)
def assemble_task(
    data_root: str, adversary: str, config: DatasetConfig, extra: tuple[str, str] | None
) -> tuple[str, list[tuple[str, str]], bool]:
    """Record the dataset of ``adversary``'s footage (plus the ``extra`` clips' output).

    Returns its key, its members and whether it is new.
    """
    with connect(data_paths(data_root).db) as con:
        members = candidate_members(con, adversary, config, dataset_code())
        if extra is not None:
            members.append(extra)
        key, new = record_dataset(con, adversary, config, members)
    return key, members, new
