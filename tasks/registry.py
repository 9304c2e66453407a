"""Every stage, declared once: its name, subject, settings, upstream stages, plan and migrations.

The flows' plan table, the settings sections, the CLI's stage choices, `status`, `check` and the
dashboard's stage lists all read this registry. A stage outside this package joins with
`register` (and leaves with `unregister`): its folder, one `Stage`, and its migrations.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, fields
from enum import StrEnum
from importlib.resources.abc import Traversable
from pathlib import Path

from storage.db import add_migrations, remove_migrations
from tasks.dataset.config import DatasetConfig
from tasks.evaluate.config import EvaluateConfig
from tasks.ingest.config import IngestConfig
from tasks.lift.config import LiftStageConfig
from tasks.pose.config import PoseConfig
from tasks.runner import StagePlan
from tasks.stage_inputs import DatasetInputs, Declared, LiftInputs, NoInputs, PoseInputs
from tasks.train.config import TrainConfig


class Subject(StrEnum):
    """What one output of a stage is of: a video file (ingest, before it has an id), a
    registered video, an adversary's assembled dataset, or a training run."""

    FILE = "file"
    VIDEO = "video"
    DATASET = "dataset"
    RUN = "run"


@dataclass(frozen=True)
class Stage:
    """One stage.

    name: its name, the prefix of its tables and its settings' section; subject: what each
    output is of; settings: its settings class (a frozen dataclass of `tasks.config.setting`
    fields); upstream: the stages it needs, by name (for a stage of a dataset or a run, the
    first is the stage whose output that is); inputs: the frozen dataclass its plan is given,
    one field per upstream output it reads (its key), by the upstream stage's name (ingest's:
    `Declared`); plan:
    ``"module:function"``, the function ``(paths, settings, subject, inputs) -> StagePlan``,
    imported only when the stage runs (training's imports torch, which the dashboard, reading
    this registry, must not); migrations: a folder of ``NNN_name.sql`` files creating its tables,
    for a stage whose tables are not in ``storage/migrations``.
    """

    name: str
    subject: Subject
    settings: type
    upstream: tuple[str, ...]
    inputs: type
    plan: str
    migrations: Path | Traversable | None = None

    def planner(self) -> Callable[..., StagePlan]:
        module, _, function = self.plan.partition(":")
        return getattr(importlib.import_module(module), function)


_STAGES: dict[str, Stage] = {}


def register(stage: Stage) -> Stage:
    """Add ``stage`` after the stages registered so far (its upstream ones among them)."""
    if not re.fullmatch(r"[a-z][a-z0-9]*", stage.name):
        # Its tables are "<name>_...", and `storage.check` reads the stage off that prefix.
        raise ValueError(f"a stage's name is lowercase letters and digits, got {stage.name!r}")
    if stage.name in _STAGES:
        raise ValueError(f"a stage named {stage.name!r} is registered already")
    unknown = [u for u in stage.upstream if u not in _STAGES]
    if unknown:
        raise ValueError(f"stage {stage.name!r}: unknown upstream stages {unknown}")
    read = stage.upstream[1:] if stage.subject in (Subject.DATASET, Subject.RUN) else stage.upstream
    if stage.subject is not Subject.FILE and tuple(f.name for f in fields(stage.inputs)) != read:
        raise ValueError(
            f"stage {stage.name!r}: its inputs' fields must be the upstream outputs it reads, "
            f"{list(read)}"
        )
    if stage.migrations is not None:
        add_migrations(stage.name, stage.migrations)
    _STAGES[stage.name] = stage
    return stage


def unregister(name: str) -> None:
    """Remove a stage no other stage depends on (a stage registered for a while, as by a test)."""
    needed = [s.name for s in _STAGES.values() if name in s.upstream]
    if needed:
        raise ValueError(f"stage {name!r} is upstream of {needed}")
    del _STAGES[name]
    remove_migrations(name)


@contextmanager
def registered(stage: Stage) -> Iterator[Stage]:
    """``stage`` registered for the duration of the block."""
    register(stage)
    try:
        yield stage
    finally:
        unregister(stage.name)


def stages() -> tuple[Stage, ...]:
    """Every stage, in pipeline order (each after its upstream ones, as registered)."""
    return tuple(_STAGES.values())


def stage(name: str) -> Stage:
    try:
        return _STAGES[name]
    except KeyError:
        raise ValueError(f"unknown stage {name!r}; known: {', '.join(_STAGES)}") from None


def names(*subjects: Subject) -> tuple[str, ...]:
    """The stages' names in pipeline order, only those of ``subjects`` when given."""
    return tuple(s.name for s in _STAGES.values() if not subjects or s.subject in subjects)


def per_video() -> tuple[str, ...]:
    """The stages run for each video (ingest's file, then the registered video)."""
    return names(Subject.FILE, Subject.VIDEO)


def until(name: str | None) -> tuple[str, ...]:
    """The stages a run up to ``name`` runs: ``name`` and every stage it needs, in pipeline
    order; every stage when None."""
    if name is None:
        return names()
    wanted = {stage(name).name}
    for s in reversed(stages()):
        if s.name in wanted:
            wanted.update(s.upstream)
    return tuple(n for n in names() if n in wanted)


def downstream(name: str) -> tuple[str, ...]:
    """``name`` and every stage that depends on it, in pipeline order."""
    found = {stage(name).name}
    for s in stages():
        if found & set(s.upstream):
            found.add(s.name)
    return tuple(n for n in names() if n in found)


register(Stage("ingest", Subject.FILE, IngestConfig, (), Declared, "tasks.ingest.task:ingest_plan"))
register(
    Stage("pose", Subject.VIDEO, PoseConfig, ("ingest",), PoseInputs, "tasks.pose.task:pose_plan")
)
register(
    Stage(
        "lift",
        Subject.VIDEO,
        LiftStageConfig,
        ("ingest", "pose"),
        LiftInputs,
        "tasks.lift.task:lift_plan",
    )
)
register(
    Stage(
        "dataset",
        Subject.VIDEO,
        DatasetConfig,
        ("ingest", "lift"),
        DatasetInputs,
        "tasks.dataset.task:dataset_plan",
    )
)
# Training's subject is the adversary's dataset assembled from every video's dataset output.
register(
    Stage(
        "train", Subject.DATASET, TrainConfig, ("dataset",), NoInputs, "tasks.train.task:train_plan"
    )
)
register(
    Stage(
        "evaluate",
        Subject.RUN,
        EvaluateConfig,
        ("train",),
        NoInputs,
        "tasks.evaluate.task:evaluate_plan",
    )
)
