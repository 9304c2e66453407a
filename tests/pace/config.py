"""The pace stage's settings."""

from dataclasses import dataclass

from models.settings import setting


@dataclass(frozen=True)
class PaceConfig:
    percentile: float = setting(50.0, "Which percentile of the pelvis's speed to keep (0-100).")

    def __post_init__(self) -> None:
        if not 0.0 <= self.percentile <= 100.0:
            raise ValueError(f"pace.percentile must be in [0, 100], got {self.percentile}")
