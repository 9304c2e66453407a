"""The pipeline's config: one typed section per stage, read from ``ringside.toml``."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from models.maaip.config import TrainConfig
from tasks.config import apply_overrides, build, defaults_toml, read_toml
from tasks.dataset.config import DatasetConfig
from tasks.evaluate.config import EvaluateConfig
from tasks.ingest.config import IngestConfig
from tasks.lift.config import LiftStageConfig
from tasks.pose.config import PoseConfig

# Stage name -> its config class, in pipeline order. A stage joins here when it exists.
SECTIONS: dict[str, type] = {
    "ingest": IngestConfig,
    "pose": PoseConfig,
    "lift": LiftStageConfig,
    "dataset": DatasetConfig,
    "train": TrainConfig,
    "evaluate": EvaluateConfig,
}
# The stages `video_to_opponent` runs per video; training runs on an assembled dataset.
STAGES: tuple[str, ...] = ("ingest", "pose", "lift", "dataset")
# Every stage of `video_to_opponent` in order: the per-video ones, then training on the
# adversary's assembled dataset and the evaluation (and export) of that run.
PIPELINE_STAGES: tuple[str, ...] = (*STAGES, "train", "evaluate")
# `ringside demo`'s settings over the defaults: a training run the demo can wait for, ended by
# its wall-clock budget at a checkpoint (README, "The demo": what 8 minutes give).
DEMO_SETTINGS: dict[str, str] = {
    "train.minutes": "8",
    "train.iterations": "100000",
    "train.checkpoint_every": "50",
}
DEFAULT_CONFIG_FILE = Path("ringside.toml")
HEADER = """Ringside settings. Every value here is the built-in default; change what you need.
Any setting can also be given on the command line as --SECTION-NAME VALUE, e.g.
`ringside process fight.mp4 --adversary X --ingest-cut-threshold 0.5 --pose-tracker-alpha 0.6`.
Changing a stage's settings reruns that stage and the stages after it, nothing else.
This file is written by `ringside config`."""


def defaults_text() -> str:
    """The documented defaults of every stage, as the TOML text ``ringside.toml`` ships with."""
    return defaults_toml(SECTIONS, HEADER)


@dataclass(frozen=True)
class PipelineConfig:
    ingest: IngestConfig = field(default_factory=IngestConfig)
    pose: PoseConfig = field(default_factory=PoseConfig)
    lift: LiftStageConfig = field(default_factory=LiftStageConfig)
    dataset: DatasetConfig = field(default_factory=DatasetConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    evaluate: EvaluateConfig = field(default_factory=EvaluateConfig)

    def as_dict(self) -> dict[str, dict[str, Any]]:
        return {name: dataclasses.asdict(getattr(self, name)) for name in SECTIONS}


def from_tables(tables: dict[str, Any]) -> PipelineConfig:
    """A checked config from TOML tables (or a flow parameter); missing sections take defaults."""
    unknown = sorted(set(tables) - set(SECTIONS))
    if unknown:
        raise ValueError(f"config has unknown sections {unknown}; known: {list(SECTIONS)}")
    return PipelineConfig(
        **{name: build(cls, tables.get(name, {}), section=name) for name, cls in SECTIONS.items()}
    )


def load_config(path: Path | None = None, overrides: list[str] | None = None) -> PipelineConfig:
    """Defaults, then ``path`` (or ``./ringside.toml`` when present), then ``overrides``.

    An explicitly given ``path`` must exist; the default file is optional.
    """
    if path is None:
        tables = read_toml(DEFAULT_CONFIG_FILE) if DEFAULT_CONFIG_FILE.exists() else {}
    else:
        tables = read_toml(path)
    return from_tables(apply_overrides(tables, overrides or []))
