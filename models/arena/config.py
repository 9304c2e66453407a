"""The arena's settings (`EnvConfig`): rates, episode length, fall rule, starts, batch size and
how the batch is stepped. The trainer's config holds one (`models.maaip.config.TrainerConfig.env`,
the `train.env` section of ringside.toml)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from models.settings import setting

STEPPINGS = ("rollout", "threads", "warp")
RESET_VELOCITIES = ("zero", "clip", "reference")


@dataclass(frozen=True)
class EnvConfig:
    """The training environment: rates, episode length, fall rule, batch size, stepping."""

    policy_hz: int = setting(30, "Policy queries per simulated second (MAAIP §5.1: 30 Hz).")
    substeps: int = setting(
        4,
        "Physics steps per policy step; the timestep is 1 / (policy_hz * substeps): 2 gives "
        "the paper's 60 Hz physics (§5.1), 4 gives 120 Hz, the default: holding the rest pose "
        "with action noise 0.02 (tests/test_standing.py), the default body fell in 2.2-3.3 s "
        "at 60 Hz, where at 120 Hz it stands 30 s.",
    )
    episode_s: float = setting(
        20.0,
        "Seconds after which an episode times out (not terminal for bootstrapping); long enough "
        "that a policy's mean episode length can show it stays up past 10 s.",
    )
    fall_height_m: float = setting(
        0.8,
        "A fighter whose head sphere's centre is below this height (m) has fallen, as has one "
        "touching the floor with anything but its feet and shins. Standing, the default head is "
        "at 1.67 m; a deep duck brings it to about 1.2 m.",
    )
    reset_velocity: str = setting(
        "zero",
        "Velocities an episode starts with: 'zero' (the lifted ones are noisy: joint speeds of "
        "6 rad/s at the 95th percentile on the demo, 26 at most), 'clip' (the reference's, each "
        "speed clipped to reset_speed_limit) or 'reference' (as lifted). On the demo's frames, "
        "which lean (centre of mass 13-15 cm from the feet's midpoint), resting, holding the "
        "frame or playing the clip fell in 0.74-0.84 s with any of the three.",
    )
    reset_speed_limit: float = setting(
        3.0, "With reset_velocity 'clip': the largest joint and root speed kept (rad/s, m/s)."
    )
    standing_share: float = setting(
        0.5,
        "Share (0-1) of episode starts with both fighters standing still in their guard "
        "(models.humanoid.stance) where the drawn reference frame has them (AMP's hybrid "
        "initialisation); the rest start from the frames. The demo's frames are mid-stride and "
        "lean: holding any of them fell in 0.8 s, so without standing starts few episodes teach "
        "balance.",
    )
    num_envs: int = setting(64, "N: environments stepped together, each with both agents.")
    threads: int = setting(2, "Worker threads that step the environments (cores to use).")
    stepping: str = setting(
        "rollout",
        "How the batch is stepped: 'rollout' (mujoco.rollout, contacts from sensors; measured "
        "faster) or 'threads' (own thread pool over the MjData, contacts from MjData.contact, "
        "bit-identical to stepping the environments one by one) or 'warp' (MuJoCo Warp: every "
        "environment a world of one batch, on the GPU where train.device is one, else on the "
        "CPU, where it is slower (benchmarks/train_speed.py --stepping warp); "
        "models/arena/stepping/warp.py).",
    )

    def __post_init__(self) -> None:
        for name in ("policy_hz", "substeps", "num_envs", "threads"):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
                raise ValueError(f"EnvConfig.{name} must be an integer >= 1, got {value!r}")
        for name in ("episode_s", "fall_height_m"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"EnvConfig.{name} must be a positive number, got {value!r}")
        if self.reset_velocity not in RESET_VELOCITIES:
            raise ValueError(
                f"EnvConfig.reset_velocity must be one of {RESET_VELOCITIES}, "
                f"got {self.reset_velocity!r}"
            )
        if not (math.isfinite(self.reset_speed_limit) and self.reset_speed_limit > 0):
            raise ValueError(
                f"EnvConfig.reset_speed_limit must be positive, got {self.reset_speed_limit!r}"
            )
        if not (math.isfinite(self.standing_share) and 0 <= self.standing_share <= 1):
            raise ValueError(
                f"EnvConfig.standing_share must be in [0, 1], got {self.standing_share!r}"
            )
        if self.stepping not in STEPPINGS:
            raise ValueError(
                f"EnvConfig.stepping must be one of {STEPPINGS}, got {self.stepping!r}"
            )

    @property
    def timestep(self) -> float:
        """Physics timestep in seconds."""
        return 1.0 / (self.policy_hz * self.substeps)

    @property
    def max_steps(self) -> int:
        """Policy steps in an episode that does not end early."""
        return max(1, round(self.episode_s * self.policy_hz))
