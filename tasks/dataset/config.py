"""The dataset stage's config."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from models.settings import setting

# The MSc thesis's actor (Saarland 2021, §3.1): 1.90 m tall, recorded at 60 Hz. His arm
# (shoulder to wrist) is taken as 0.332 of his height, the upper arm plus forearm of Winter's
# segment table (Biomechanics and Motor Control of Human Movement, 4th ed., Table 4.1).
THESIS_ARM_M = 0.332 * 1.90
THESIS_RATE_HZ = 60.0


@dataclass(frozen=True)
class PunchConfig:
    """Automatic punch labelling (MSc thesis, Algorithms 1 and 2)."""

    search_threshold_m: float = setting(
        0.04,
        "Algorithm 1's Search_Threshold for the thesis's arm (0.63 m), read as a hysteresis: "
        "the shoulder-wrist distance (or the wrist's height, for uppercuts) must rise and then "
        "fall by this much for a full extension to count; scaled by each fighter's arm length.",
    )
    punch_threshold_m: float = setting(
        0.19,
        "Algorithm 2's Punch_Threshold for the thesis's arm (0.63 m): how far the wrist comes "
        "back towards the shoulder to start or end a punch; scaled by arm length.",
    )
    window_s: float = setting(
        25 / THESIS_RATE_HZ,
        "Algorithm 2's longest search from the full extension back to a punch's start, and "
        "from the end of a held extension on to its end (the thesis's 25 frames at 60 Hz).",
    )


@dataclass(frozen=True)
class DatasetConfig:
    """How motions become MAAIP demonstrations, labels and fighter statistics."""

    min_clip_s: float = setting(
        1.0, "Shortest clip kept (seconds); clips are cut at shot cuts and at gaps."
    )
    max_bridge_steps: int = setting(
        2,
        "Gaps of at most this many 30 Hz steps inside a fighter's motion (a step the lift or "
        "the guard below dropped), within one shot and one split, are filled by interpolation "
        "rather than cutting the clip in two (0: never; tasks/dataset/bridging.py says what it "
        "costs, benchmarks/gap_bridging.py measures it).",
    )
    validation_fraction: float = setting(
        0.15, "Share of each video's time, at its end, held out for validation."
    )
    extra_clips: str = setting(
        "",
        "Folder of extra single-actor clips in DeepMimic's motion format (*.txt) added to the "
        "single-actor set; empty adds none.",
    )
    max_root_speed_m_s: float = setting(
        8.0,
        "Steps where a fighter's pelvis moves faster than this (m/s) are left out, as gaps: no "
        "boxer moves so (the lift's own gate, lift.gates.max_root_speed_m_s, should have caught "
        "them; this is the last guard before training sees them).",
    )
    max_fighter_distance_m: float = setting(
        10.0,
        "Steps where the two fighters' pelvises are further apart than this (m) are left out of "
        "both fighters' motion.",
    )
    punch: PunchConfig = field(default_factory=PunchConfig)

    def __post_init__(self) -> None:
        for name in ("max_root_speed_m_s", "max_fighter_distance_m"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"dataset.{name} must be a positive number, got {value!r}")
        if isinstance(self.max_bridge_steps, bool) or not (
            isinstance(self.max_bridge_steps, int) and self.max_bridge_steps >= 0
        ):
            raise ValueError(
                "dataset.max_bridge_steps must be a whole number >= 0, "
                f"got {self.max_bridge_steps!r}"
            )
        if self.min_clip_s <= 0:
            raise ValueError(f"dataset.min_clip_s must be positive, got {self.min_clip_s}")
        if not 0.0 <= self.validation_fraction < 1.0:
            raise ValueError(
                f"dataset.validation_fraction must be in [0, 1), got {self.validation_fraction}"
            )
        p = self.punch
        if p.search_threshold_m <= 0 or p.punch_threshold_m <= 0 or p.window_s <= 0:
            raise ValueError("dataset.punch thresholds and window must be positive")
