"""The pipeline's config: one typed section per stage, read from ``ringside.toml``."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from storage.paths import DataPaths, data_paths
from tasks import registry
from tasks.config import apply_overrides, build, defaults_toml, read_toml


def sections() -> dict[str, type]:
    """Stage name -> its settings class, in pipeline order (`tasks.registry`)."""
    return {stage.name: stage.settings for stage in registry.stages()}


# `ringside demo`'s settings over the defaults: a training run the demo can wait for, ended by
# its wall-clock budget at a checkpoint (docs/evaluate.md, "The demo": what 8 minutes give).
DEMO_SETTINGS: dict[str, str] = {
    "train.minutes": "5",
    "train.iterations": "100000",
    "train.checkpoint_every": "50",
}
# The demo's tracker, trained on its dataset before MAAIP's run (on top of DEMO_SETTINGS): by
# iterations, not minutes, so that whether it finishes the sample's one clip (and so whether
# there is a matched opponent) does not depend on the machine's speed; 250 took 3 minutes here.
DEMO_TRACKER_SETTINGS: tuple[str, ...] = (
    "train.objective=track",
    "train.minutes=0",
    "train.iterations=250",
)
DEFAULT_CONFIG_FILE = Path("ringside.toml")
HEADER = """Ringside settings. Every value here is the built-in default; change what you need.
Any setting can also be given on the command line as --SECTION-NAME VALUE, e.g.
`ringside process fight.mp4 --adversary X --ingest-cut-threshold 0.5 --pose-tracker-alpha 0.6`.
Changing a stage's settings reruns that stage and the stages after it, nothing else.
This file is written by `ringside config`."""


def defaults_text() -> str:
    """The documented defaults of every stage, as the TOML text ``ringside.toml`` ships with."""
    return defaults_toml(sections(), HEADER)


@dataclass(frozen=True)
class PipelineConfig:
    """Every stage's settings, one section per registered stage: ``config.pose`` is the pose
    stage's."""

    sections: Mapping[str, Any] = field(
        default_factory=lambda: {name: cls() for name, cls in sections().items()}
    )

    def __getattr__(self, name: str) -> Any:
        try:
            return self.__dict__["sections"][name]
        except KeyError:
            raise AttributeError(name) from None

    def as_dict(self) -> dict[str, dict[str, Any]]:
        return {name: dataclasses.asdict(value) for name, value in self.sections.items()}


def from_tables(tables: dict[str, Any]) -> PipelineConfig:
    """A checked config from TOML tables (or a flow parameter); missing sections take defaults."""
    known = sections()
    unknown = sorted(set(tables) - set(known))
    if unknown:
        raise ValueError(f"config has unknown sections {unknown}; known: {list(known)}")
    return PipelineConfig(
        {name: build(cls, tables.get(name, {}), section=name) for name, cls in known.items()}
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


def flow_inputs(data_root: str, config: dict | None) -> tuple[DataPaths, PipelineConfig]:
    """A flow's parameters turned back into what the code below takes: the data directory's
    paths and the checked settings. Prefect's parameters are JSON, so a flow is given the
    directory as a string and the settings as tables; every flow crosses back here, once.

    With the results in a lake, a run on a worker of another machine keeps that machine's own
    data directory (its claims, temporary files, Prefect home: `RINGSIDE_DATA` of the process,
    which `ringside worker --data DIR` sets), not the scheduler's path, which may not exist
    there; what the machines share is the lake and its shared folder."""
    paths = data_paths(data_root)
    if paths.lake is not None and os.environ.get("RINGSIDE_DATA"):
        paths = data_paths(os.environ["RINGSIDE_DATA"])
    return paths, from_tables(config or {})
