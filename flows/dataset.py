"""The dataset stage as flows: one video's demonstrations, then one adversary's dataset."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

from prefect import flow
from prefect.runtime import flow_run

from flows.config import from_tables
from flows.runs import StageSummary, reuse_or_run
from models.humanoid.boxer import BoneLengths
from storage.db import connect
from storage.files import sha256_file
from storage.keys import digest, stage_key
from storage.paths import data_paths
from tasks.dataset.stage import STAGE, dataset_code, dataset_key
from tasks.dataset.store import candidate_members, member_bones
from tasks.dataset.task import assemble_task, dataset_call, extra_clips_call
from tasks.errors import BadInput
from tasks.ingest.store import load_ingest
from tasks.runner import StageCall


def _run_name() -> str:
    return f"dataset-{flow_run.parameters['video_id'][:12]}"


@flow(name="dataset", flow_run_name=_run_name)
def dataset_flow(
    data_root: str,
    video_id: str,
    ingest_key: str,
    lift_key: str,
    config: dict | None = None,
    force: bool = False,
) -> StageSummary:
    """Cut one video's lifted motion into MAAIP demonstrations, labels and statistics."""
    settings = from_tables(config or {}).dataset
    with connect(data_paths(data_root).db, read_only=True) as con:
        ingest = load_ingest(con, video_id, ingest_key)
    key = dataset_key(settings, lift_key)

    def call() -> StageCall:
        return dataset_call(data_root, ingest, lift_key, settings, key)

    result, state = reuse_or_run(
        data_root, stage=STAGE, video_id=video_id, key=key, force=force, call=call
    )
    return StageSummary(video_id, ingest.path, STAGE, key, state, result.seconds, result.notes)


def _extra_clips(
    data_root: str, folder: str, bones: list[BoneLengths], force: bool
) -> tuple[str, str]:
    """The extra clips' dataset output on the fighters' ``bones``: (its pseudo video id, key),
    computed when missing."""
    path = Path(folder)
    if not path.is_dir():
        raise BadInput(folder, "not a folder (dataset.extra_clips)")
    files = {p.name: sha256_file(p) for p in sorted(path.glob("*.txt"))}
    if not files:
        raise BadInput(folder, "no *.txt motion clips in this folder (dataset.extra_clips)")
    upstream = {"files": files, "bones": [asdict(b) for b in bones]}
    video_id = "extra-" + digest(upstream)[:20]
    key = stage_key(STAGE, {"extra_clips": "files"}, dataset_code(), upstream)

    def call() -> StageCall:
        return extra_clips_call(str(path.resolve()), files, bones, video_id, key)

    reuse_or_run(data_root, stage=STAGE, video_id=video_id, key=key, force=force, call=call)
    return video_id, key


@flow(name="dataset-assemble")
def assemble_flow(
    data_root: str, adversary: str, config: dict | None = None, force: bool = False
) -> StageSummary:
    """Join every processed video of ``adversary`` (and any extra clips) into one dataset.

    The summary's key is the dataset key training takes.
    """
    settings = from_tables(config or {}).dataset
    extra = None
    if settings.extra_clips:
        with connect(data_paths(data_root).db, read_only=True) as con:
            members = candidate_members(con, adversary, settings, dataset_code())
            bones = member_bones(con, members)
        extra = _extra_clips(data_root, settings.extra_clips, bones, force)
    key, members, new = assemble_task(data_root, adversary, settings, extra)
    notes = (f"dataset {key} of {adversary}: {len(members)} outputs",)
    return StageSummary(
        "", adversary, "dataset-assemble", key, "done" if new else "cached", 0.0, notes
    )
