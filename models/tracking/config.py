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
    anchor_m: float = setting(
        0.0,
        "In training, a reference whose pelvis strays further than this (m, along the floor) "
        "from the simulated pelvis is moved back under it, as the matched opponent's motion is in "
        "a bout (`MatchConfig.anchor_m`; DReCon keeps its kinematic root within 0.5 m of the "
        "simulated body), so that a fighter left behind by its motion learns to catch up instead "
        "of ending its episode at `root_limit_m`. 0: never. The gate and the replays never move "
        "their references.",
    )
    separation_m: float = setting(
        4.0,
        "Each episode places agent 0's clip with its start frame's pelvis at y = -separation/2 "
        "and agent 1's at +separation/2 (the clip's heading kept), so that the two fighters of "
        "an arena, each tracking its own clip, never meet (the clips travel 1-2 m).",
    )

    hard_start_share: float = setting(
        0.0,
        "The share of episode starts drawn where the tracker has been failing: a frame up to "
        "`hard_start_window_s` before where recent episodes ended terminally, weighted by how "
        "many did (PHC's hard-negative mining, by frame); the rest uniform over every frame "
        "(DeepMimic's reference state initialisation). 0: all uniform. Measured (docs/train.md, "
        "Time to the gate): 0.5 holds the gate on clean clips (DeepMimic's) 3x sooner, but on "
        "lifted footage, where some frames no body can follow, it trains worse; so 0 here.",
    )
    rest_start_share: float = setting(
        0.0,
        "The share of episode starts made at rest: the start frame's pose with no velocity, as "
        "a bout starts its fighters (`tasks.opponent.spar`) and as a matched opponent stands up "
        "again after a fall; the rest start with the clip's velocities (DeepMimic).",
    )
    together_share: float = setting(
        0.0,
        "The share of episode starts made with both fighters together, as filmed: both agents "
        "at the same frame of one clip of the footage (or one matched stream) and where it has "
        "them, so that contact, clinches and punches that land are part of training; the rest "
        "start each agent on its own clip at its slot (`separation_m`).",
    )
    push_every_s: float = setting(
        0.0,
        "The mean time (s) between random pushes on each training fighter (`models.arena."
        "pushes`: an object thrown at a random body part; DReCon threw one about every "
        "second); 0: none. Training only: the gate and the replays are never pushed.",
    )
    push_mass_min_kg: float = setting(1.0, "The lightest object a push throws (kg; DReCon: 1).")
    push_mass_max_kg: float = setting(10.0, "The heaviest object a push throws (kg; DReCon: 10).")
    push_speed_mps: float = setting(
        5.0, "The speed (m/s) a push's object is thrown at (DReCon: 5)."
    )
    hard_start_window_s: float = setting(
        1.0, "How far (s) before a failure a hard start may be drawn (`hard_start_share`)."
    )
    hard_start_memory_steps: float = setting(
        2048.0,
        "The failure counts that weight the hard starts decay by 1/e over this many policy "
        "steps (about 32 iterations with the defaults), so they follow what the tracker fails "
        "at now.",
    )
    value_sees_partner: bool = setting(
        False,
        "Whether the value also reads the other agent's observation (MAPPO's centralised value, "
        "as MAAIP's). The two trackers of an arena never meet, and the other's ending is a "
        "time-out for each (bootstrapped), so it carries nothing to predict; off, the value's "
        "input is half as wide (measured: the PPO update a fifth cheaper, "
        "`benchmarks/train_speed.py --objective track`).",
    )
    matched_streams: int = setting(
        0,
        "How many streams of matched motion are added to the train stage's clips: both "
        "fighters' train footage played by their motion matchers against each other "
        "(`models.tracking.matched.matched_streams`), transitions and all, as the matched "
        "opponent plays it (DReCon trains its tracker on such streams). 0: none.",
    )
    matched_stream_s: float = setting(10.0, "Each matched stream's length (s).")
    bouts: bool = setting(
        False,
        "Train in bouts (`models.tracking.bouts`): both fighters start standing in their guards "
        "and each tracks what its motion matcher picks from its own footage against the other, "
        "as a matched opponent plays (DReCon trains its tracker on its matcher's output). The "
        "starts, clips and streams settings above then do not apply; the pushes do. Off: the "
        "footage's clips from their own states.",
    )
    gate_every: int = setting(
        20,
        "Every this many iterations the train stage gates the tracker (`track_gate` on the train "
        "clips): the `gate_*` iteration metrics; 0 never.",
    )
    gate_finished_pct: float = setting(90.0, "The gate: at least this share of clips finished (%).")
    gate_body_error_cm: float = setting(5.0, "The gate: mean body error at most this (cm).")
    gate_root_error_cm: float = setting(10.0, "The gate: mean root error at most this (cm).")
    gate_window: int = setting(
        5, "The gate is held when met in `gate_needed` of the last this many checks."
    )
    gate_needed: int = setting(3, "How many of the last `gate_window` checks must meet the gate.")
    stop_when_held: bool = setting(
        True, "The train stage ends a tracker run at the first check where the gate is held."
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
            "hard_start_window_s",
            "hard_start_memory_steps",
            "matched_stream_s",
            "push_mass_min_kg",
            "push_mass_max_kg",
            "push_speed_mps",
            "gate_body_error_cm",
            "gate_root_error_cm",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"train.track.{name} must be positive, got {value}")
        if not 0 <= self.rest_start_share <= 1:
            raise ValueError(
                f"train.track.rest_start_share must be between 0 and 1, got {self.rest_start_share}"
            )
        if not 0 <= self.together_share <= 1:
            raise ValueError(
                f"train.track.together_share must be between 0 and 1, got {self.together_share}"
            )
        if not (math.isfinite(self.anchor_m) and self.anchor_m >= 0):
            raise ValueError(f"train.track.anchor_m must be 0 or positive, got {self.anchor_m}")
        if not (math.isfinite(self.push_every_s) and self.push_every_s >= 0):
            raise ValueError(
                f"train.track.push_every_s must be 0 or positive, got {self.push_every_s}"
            )
        if self.push_mass_min_kg > self.push_mass_max_kg:
            raise ValueError(
                f"train.track.push_mass_min_kg ({self.push_mass_min_kg}) must not exceed "
                f"push_mass_max_kg ({self.push_mass_max_kg})"
            )
        if not 0 <= self.hard_start_share <= 1:
            raise ValueError(
                f"train.track.hard_start_share must be between 0 and 1, got {self.hard_start_share}"
            )
        if not 0 <= self.gate_finished_pct <= 100:
            raise ValueError(
                f"train.track.gate_finished_pct must be between 0 and 100, got "
                f"{self.gate_finished_pct}"
            )
        if self.matched_streams < 0:
            raise ValueError(
                f"train.track.matched_streams must be >= 0, got {self.matched_streams}"
            )
        if self.gate_every < 0:
            raise ValueError(f"train.track.gate_every must be >= 0, got {self.gate_every}")
        if not 1 <= self.gate_needed <= self.gate_window:
            raise ValueError(
                f"train.track.gate_needed ({self.gate_needed}) must be between 1 and "
                f"gate_window ({self.gate_window})"
            )
