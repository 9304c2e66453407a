"""The dataset stage's plans: one video's demonstrations, the extra clips, the assembly of an
adversary's dataset from them, and the synthetic adversary (`tasks.dataset.synthetic`)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from prefect import task
from prefect.cache_policies import NO_CACHE

from models.humanoid.boxer import BoneLengths
from models.humanoid.motion import RATE
from storage.db import connect
from storage.files import sha256_file
from storage.paths import DataPaths
from tasks.dataset import synthetic
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
from tasks.runner import StagePlan
from tasks.stage_inputs import DatasetInputs


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


def synthetic_motion_plan(
    paths: DataPaths, config: synthetic.SyntheticConfig, bones: Mapping[str, BoneLengths]
) -> StagePlan:
    """The synthetic adversary's motion (`synthetic.synthetic_motion`) on ``bones`` (adversary,
    opponent), as a lift output of its pseudo video."""
    files = synthetic.clip_files(paths.assets)
    spec = synthetic.motion_spec(config, {n: sha256_file(p) for n, p in files.items()}, bones)

    def compute():
        clips = synthetic.retargeted_clips(files, bones)
        frames = {name: len(q) for name, q in clips[next(iter(clips))].items()}
        exchanges = synthetic.performance(frames, config)
        motion = synthetic.synthetic_motion(clips, bones, exchanges, config.distance_m)
        return synthetic.motion_output(motion, exchanges)

    return StagePlan(spec, "synthetic adversary", compute)


def synthetic_dataset_plan(
    paths: DataPaths,
    config: DatasetConfig,
    settings: synthetic.SyntheticConfig,
    video_id: str,
    lift_key: str,
) -> StagePlan:
    """The dataset stage's output of the synthetic motion ``lift_key`` of pseudo video
    ``video_id``: `build_dataset` on its exchanges as shots, then split by its windows."""
    files = synthetic.clip_files(paths.assets)
    effective = synthetic.dataset_config(config, settings)
    spec = dataset_spec(effective, video_id, lift_key)

    def compute():
        exchanges = synthetic.performance(synthetic.clip_frames(files), settings)
        with connect(paths.db, read_only=True) as con:
            fighters = load_motion(con, video_id, lift_key)
        if not fighters:
            raise BadInput(STAGE, f"synthetic motion {lift_key} of {video_id} is empty")
        output = build_dataset(
            fighters, shots=synthetic.shots_of(exchanges), fps=RATE, config=effective
        )
        return synthetic.split_by_windows(output, exchanges)

    return StagePlan(spec, "synthetic adversary", compute)


@task(name="dataset-assemble", cache_policy=NO_CACHE)
def assemble_synthetic_task(
    paths: DataPaths, name: str, config: DatasetConfig, member: tuple[str, str]
) -> tuple[str, bool, str | None]:
    """Record the dataset ``name`` of the synthetic adversary's one dataset output ``member``
    (video_id, key). Returns its key, whether it is new and why it cannot be trained on (None
    when it can)."""
    with connect(paths.db) as con:
        key, new = record_dataset(con, name, config, [member])
        unusable = dataset_verdicts(con)[key]
    return key, new, unusable
