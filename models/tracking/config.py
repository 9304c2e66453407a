"""The tracker's settings (`TrackConfig`, the `[train.track]` section): DeepMimic's reward
weights and scales, early termination and where each agent's clip is placed."""

from __future__ import annotations

import math
from dataclasses import dataclass

from models.settings import setting


@dataclass(frozen=True)
class TrackConfig:
    """The tracking objective (`TrainerConfig.objective` 'track', `models.tracking`): each
    agent follows a reference clip, its PD targets the clip's next frame plus the policy's
    correction (DReCon, Bergamin et al. 2019), rewarded by DeepMimic's imitation reward (Peng et
    al., ACM TOG 37(4), 2018: r = w_p r_p + w_v r_v + w_e r_e + w_c r_c)."""

    w_pose: float = setting(0.65, "w^p of the pose term r_p = exp(-2 sum_j angle_j^2) (DeepMimic).")
    w_velocity: float = setting(
        0.1, "w^v of the velocity term r_v = exp(-0.1 sum_j |w_j - w^_j|^2) (DeepMimic)."
    )
    w_end_effector: float = setting(
        0.15, "w^e of the end-effector term r_e = exp(-40 sum_e |p_e - p^_e|^2) (DeepMimic)."
    )
    w_com: float = setting(
        0.1, "w^c of the centre-of-mass term r_c = exp(-10 |p_c - p^_c|^2) (DeepMimic)."
    )
    pose_scale: float = setting(2.0, "The pose term's scale, 1/rad^2 (DeepMimic: 2).")
    velocity_scale: float = setting(0.1, "The velocity term's scale, s^2/rad^2 (DeepMimic: 0.1).")
    end_effector_scale: float = setting(
        40.0, "The end-effector term's scale, 1/m^2 (DeepMimic: 40)."
    )
    com_scale: float = setting(10.0, "The centre-of-mass term's scale, 1/m^2 (DeepMimic: 10).")
    root_limit_m: float = setting(
        0.5,
        "An agent whose pelvis is further than this (m) from its reference's ends its episode, "
        "terminally (early termination), as does a fall (EnvConfig's rule).",
    )
    separation_m: float = setting(
        4.0,
        "Each episode places agent 0's clip with its start frame's pelvis at y = -separation/2 "
        "and agent 1's at +separation/2 (the clip's heading kept), so that the two fighters of "
        "an arena, each tracking its own clip, never meet (the clips travel 1-2 m).",
    )

    def __post_init__(self) -> None:
        for name in ("w_pose", "w_velocity", "w_end_effector", "w_com"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"train.track.{name} must be non-negative, got {value}")
        if self.w_pose + self.w_velocity + self.w_end_effector + self.w_com <= 0:
            raise ValueError("train.track: the four reward weights must not all be 0")
        for name in (
            "pose_scale",
            "velocity_scale",
            "end_effector_scale",
            "com_scale",
            "root_limit_m",
            "separation_m",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"train.track.{name} must be positive, got {value}")
