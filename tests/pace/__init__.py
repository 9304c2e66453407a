"""A tiny stage outside Ringside's own (tests/test_registry.py): each fighter's pelvis speed
over a lifted video, in a table of its own. Registering `PACE` is all it takes to join."""

from dataclasses import dataclass
from pathlib import Path

from pace.config import PaceConfig
from tasks.registry import Stage, Subject


@dataclass(frozen=True)
class PaceInputs:
    lift: str  # the lift output's key


PACE = Stage(
    "pace",
    Subject.VIDEO,
    PaceConfig,
    ("lift",),
    PaceInputs,
    "pace.task:pace_plan",
    Path(__file__).parent / "migrations",
)
