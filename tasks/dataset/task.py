"""The dataset stage's plans: one video's demonstrations, the extra clips, and the assembly of
an adversary's dataset from them."""

from __future__ import annotations

from pathlib import Path

from prefect import task
from prefect.cache_policies import NO_CACHE

from storage.db import connect
from storage.files import sha256_file
from storage.paths import DataPaths
from tasks.dataset.config import DatasetConfig
from tasks.dataset.stage import (
    STAGE,
    build_dataset,
    dataset_code,
    dataset_spec,
    extra_clip_output,
    extra_clips_spec,
)
from tasks.dataset.store import (
    candidate_members,
    dataset_verdicts,
    member_bones,
    record_dataset,
)
from tasks.errors import BadInput
from tasks.ingest.store import load_ingest
from tasks.lift.store import load_motion
from tasks.registry import DatasetInputs
from tasks.runner import StagePlan


def dataset_plan(
    paths: DataPaths, config: DatasetConfig, video_id: str, inputs: DatasetInputs
) -> StagePlan:
    """Cut lift output ``inputs.lift`` into clips, transitions, labels and statistics."""
    with connect(paths.db, read_only=True) as con:
        ingest = load_ingest(con, video_id, inputs.ingest)
    lift_key = inputs.lift
    spec = dataset_spec(config, video_id, lift_key)

    def compute():
        with connect(paths.db, read_only=True) as con:
            fighters = load_motion(con, video_id, lift_key)
        if not fighters:
            raise BadInput(STAGE, f"lift output {lift_key} of video {video_id} is empty")
        return build_dataset(
            fighters,
            shots=list(ingest.shots),
            fps=ingest.fps,
            config=config,
        )

    return StagePlan(spec, ingest.path, compute)


def extra_clips_plan(paths: DataPaths, config: DatasetConfig, adversary: str) -> StagePlan:
    """The analyst's extra single-actor clips (the DeepMimic-format ``*.txt`` of folder
    ``config.extra_clips``), retargeted onto the bodies of ``adversary``'s fighters, as one
    dataset output."""
    folder = config.extra_clips
    path = Path(folder).resolve()
    if not path.is_dir():
        raise BadInput(folder, "not a folder (dataset.extra_clips)")
    files = {p.name: sha256_file(p) for p in sorted(path.glob("*.txt"))}
    if not files:
        raise BadInput(folder, "no *.txt motion clips in this folder (dataset.extra_clips)")
    with connect(paths.db, read_only=True) as con:
        bones = member_bones(con, candidate_members(con, adversary, config, dataset_code()))
    spec = extra_clips_spec(path, files, bones)
    return StagePlan(
        spec,
        folder,
        compute=lambda: extra_clip_output(path, bones),
    )


@task(name="dataset-assemble", cache_policy=NO_CACHE)
def assemble_task(
    paths: DataPaths, adversary: str, config: DatasetConfig, extra: tuple[str, str] | None
) -> tuple[str, list[tuple[str, str]], bool, str | None]:
    """Record the dataset of ``adversary``'s footage (plus the ``extra`` clips' output).

    Returns its key, its members, whether it is new and why it cannot be trained on (None when
    it can: `store.dataset_verdicts`).
    """
    with connect(paths.db) as con:
        members = candidate_members(con, adversary, config, dataset_code())
        if extra is not None:
            members.append(extra)
        key, new = record_dataset(con, adversary, config, members)
        unusable = dataset_verdicts(con)[key]
    return key, members, new, unusable
