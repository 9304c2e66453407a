"""A tiny stage outside Ringside's own (tests/test_registry.py): each fighter's pelvis speed
over a lifted video, in a table of its own. Registering `PACE` is all it takes to join."""

from pathlib import Path

from pace.config import PaceConfig
from tasks.registry import Stage, Subject

PACE = Stage(
    "pace",
    Subject.VIDEO,
    PaceConfig,
    ("lift",),
    "pace.task:pace_plan",
    Path(__file__).parent / "migrations",
)
