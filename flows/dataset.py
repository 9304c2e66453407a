"""The adversary's dataset assembled from every processed video (and any extra clips)."""

from __future__ import annotations

from prefect import flow

from flows.config import flow_inputs
from flows.runs import StageSummary, reuse_or_run
from tasks.dataset.task import assemble_task, extra_clips_plan
from tasks.errors import BadInput


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
