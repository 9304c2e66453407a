"""The adversary's dataset assembled from every processed video (and any extra clips), and the
synthetic adversary's (`tasks.dataset.synthetic`)."""

from __future__ import annotations

from prefect import flow

from flows.config import flow_inputs
from flows.runs import StageSummary, reuse_or_run
from models.humanoid.boxer import BoneLengths
from tasks.config import build
from tasks.dataset.synthetic import SyntheticConfig
from tasks.dataset.task import (
    assemble_synthetic_task,
    assemble_task,
    extra_clips_plan,
    synthetic_dataset_plan,
    synthetic_motion_plan,
)
from tasks.errors import BadInput
from tasks.roles import ROLES


@flow(name="dataset-assemble")
def assemble_flow(
    data_root: str, adversary: str, config: dict | None = None, force: bool = False
) -> StageSummary:
    """Join every processed video of ``adversary`` (and any extra clips) into one dataset.

    The summary's key is the dataset key training takes. Raises BadInput, saying why in one
    line, when the dataset cannot be trained on (`tasks.dataset.verdict`).
    """
    paths, pipeline = flow_inputs(data_root, config)
    settings = pipeline.dataset
    extra = None
    if settings.extra_clips:
        plan = extra_clips_plan(paths, settings, adversary)
        result, _ = reuse_or_run(paths, plan, force)
        extra = (result.subject, result.key)
    key, members, new, unusable = assemble_task(paths, adversary, settings, extra)
    if unusable is not None:
        # Recorded all the same, as is every stage's output (nothing computed is lost): the
        # run fails here so that it ends saying why, and trains nothing on it.
        raise BadInput(f"dataset {key} of {adversary}", f"unusable: {unusable}")
    notes = (f"dataset {key} of {adversary}: {len(members)} outputs",)
    return StageSummary(
        "", adversary, "dataset-assemble", key, "done" if new else "cached", 0.0, notes
    )


@flow(name="synthetic-adversary")
def synthetic_adversary_flow(
    data_root: str,
    name: str,
    bones: dict[str, dict[str, float]],
    synthetic: dict | None = None,
    config: dict | None = None,
    force: bool = False,
) -> list[StageSummary]:
    """The synthetic adversary ``name`` on ``bones`` (role -> `BoneLengths` fields) as a
    dataset: its motion (a lift output), the dataset stage's output of it, and the dataset
    joining that one output, whose key (the last summary's) training takes. ``synthetic``: the
    `SyntheticConfig` settings; ``force`` recomputes both outputs.

    Raises BadInput, in one line, when the dataset cannot be trained on.
    """
    paths, pipeline = flow_inputs(data_root, config)
    settings = build(SyntheticConfig, synthetic or {}, section="synthetic")
    bodies = {role: BoneLengths(**bones[role]) for role in ROLES}
    summaries = []
    motion_plan = synthetic_motion_plan(paths, settings, bodies)
    motion, state = reuse_or_run(paths, motion_plan, force)
    summaries.append(
        StageSummary(
            motion.subject,
            motion_plan.name,
            "lift",
            motion.key,
            state,
            motion.seconds,
            motion.notes,
        )
    )
    data_plan = synthetic_dataset_plan(
        paths, pipeline.dataset, settings, motion.subject, motion.key
    )
    data, state = reuse_or_run(paths, data_plan, force)
    summaries.append(
        StageSummary(
            data.subject, data_plan.name, "dataset", data.key, state, data.seconds, data.notes
        )
    )
    key, new, unusable = assemble_synthetic_task(
        paths, name, data_plan.spec.config, (data.subject, data.key)
    )
    if unusable is not None:
        raise BadInput(f"dataset {key} of {name}", f"unusable: {unusable}")
    notes = (f"dataset {key} of {name}: train it with `ringside train --dataset {key[:12]}`",)
    summaries.append(
        StageSummary("", name, "dataset-assemble", key, "done" if new else "cached", 0.0, notes)
    )
    return summaries
