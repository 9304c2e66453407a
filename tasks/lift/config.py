"""The lift stage's config."""

from __future__ import annotations

from dataclasses import dataclass, field

from tasks.config import setting
from tasks.lift.solve import LiftConfig


@dataclass(frozen=True)
class LiftStageConfig:
    """How the camera is found and each fighter is lifted, fitted and cleaned."""

    calibration: str = setting(
        "",
        "Camera intrinsics file written by `ringside calibrate`; empty guesses them from fov_deg.",
    )
    fov_deg: float = setting(
        60.0, "Field of view (degrees, across the longer image side) assumed without calibration."
    )
    min_frames: int = setting(
        10, "A fighter seen in fewer frames of a shot is not lifted in that shot."
    )
    solve: LiftConfig = field(default_factory=LiftConfig)

    def __post_init__(self) -> None:
        if not 1.0 < self.fov_deg < 179.0:
            raise ValueError(f"lift.fov_deg must be in (1, 179), got {self.fov_deg}")
        if self.min_frames < 3:
            raise ValueError(f"lift.min_frames must be at least 3, got {self.min_frames}")
