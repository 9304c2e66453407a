"""The evaluate stage's config: how many bouts, how long, and the thresholds of the metrics.

Imports nothing heavy (no torch, no MuJoCo), so reading the settings stays cheap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from models.settings import setting


def _whole(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


@dataclass(frozen=True)
class EvaluateConfig:
    """Evaluation bouts of a trained pair of policies, and what is measured on them."""

    seed: int = setting(
        0,
        "Seeds the episodes' start frames and heading targets: the same seed gives the same "
        "bouts and so the same tables.",
    )
    episodes: int = setting(
        32, "Episodes per policy pair, run side by side (MAAIP §5.3: 32 randomly initialised)."
    )
    episode_frames: int = setting(
        1200,
        "Policy steps per episode unless a fall ends it first (MAAIP §5.3: 1200, 40 s at 30 Hz).",
    )
    heading_episodes: int = setting(
        32, "Episodes per heading policy, for the heading table (MAAIP §5.4: 32)."
    )
    heading_frames: int = setting(500, "Policy steps per heading episode (MAAIP §5.4: 500).")
    punch_target_radius_m: float = setting(
        0.15,
        "A punch is accurate when the fist ends within this distance of the opponent's head or "
        "torso at full extension (MSc thesis §6.1, eq 6.1: a head-sized sphere of 15 cm).",
    )
    video_seconds: float = setting(
        10.0,
        "Seconds of the evaluation episodes, played one after another, rendered to an H.264 "
        "MP4 (MuJoCo's renderer through EGL); 0 renders none.",
    )
    tracker: str = setting(
        "",
        "The tracker run (train.objective track; a key prefix will do) that replays the "
        "held-out footage for the two-sample test; empty: the dataset's newest.",
    )

    def __post_init__(self) -> None:
        for name in ("episodes", "episode_frames", "heading_episodes", "heading_frames"):
            value = getattr(self, name)
            if not (_whole(value) and value >= 1):
                raise ValueError(f"evaluate.{name} must be an integer >= 1, got {value!r}")
        if not _whole(self.seed) or self.seed < 0:
            raise ValueError(f"evaluate.seed must be an integer >= 0, got {self.seed!r}")
        radius = self.punch_target_radius_m
        if not (isinstance(radius, int | float) and math.isfinite(radius) and radius > 0):
            raise ValueError(
                "evaluate.punch_target_radius_m must be a positive number of metres, got "
                f"{radius!r}"
            )
        if not isinstance(self.tracker, str):
            raise ValueError(f"evaluate.tracker must be a run key prefix, got {self.tracker!r}")
        seconds = self.video_seconds
        if not (isinstance(seconds, int | float) and math.isfinite(seconds) and seconds >= 0):
            raise ValueError(
                f"evaluate.video_seconds must be a number of seconds >= 0, got {seconds!r}"
            )
