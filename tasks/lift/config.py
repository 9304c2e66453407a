"""The lift stage's config: the stage's own settings and the solver's (`LiftConfig`, kept here
and not beside the solver so that reading the settings does not import torch)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from models.settings import setting
from tasks.lift.gates import GateConfig

# Standing heights a fighter can have (m): the shortest and tallest boxers on record are well
# inside; a number outside is a typo or centimetres.
MIN_STATURE_M, MAX_STATURE_M = 1.2, 2.5


@dataclass(frozen=True)
class LiftConfig:
    """How one fighter is lifted to 3D, fitted with the humanoid and cleaned up.

    The lift's energy is a sum of squared residuals, each divided by the noise scale its
    ``*_sigma`` field names (a maximum a posteriori estimate under Gaussian noise), times its
    ``*_weight``. Defaults suit BlazePose on broadcast video at 30 fps (2D error of a few
    pixels, world-landmark error about 6 cm) and were checked on synthetic truth
    (tests/test_lift_solve.py).
    """

    reprojection_sigma_px: float = setting(
        5.0, "Expected 2D keypoint error (pixels) at confidence 1; divides reprojection errors."
    )
    reprojection_weight: float = setting(
        1.0, "Weight of the confidence-weighted (robust, Charbonnier) reprojection term."
    )
    min_confidence: float = setting(
        0.2, "2D keypoints with a lower confidence (0-1) are left out of the reprojection term."
    )
    shape_sigma_m: float = setting(
        0.06,
        "Expected error (m) of BlazePose's world landmarks about the hip centre; divides the "
        "distance of the lifted pose (about its hip centre) from them.",
    )
    shape_weight: float = setting(1.0, "Weight of the closeness-to-world-landmarks term.")
    bone_sigma_m: float = setting(
        0.005, "Allowed deviation (m) of a bone from its one length over the clip."
    )
    bone_weight: float = setting(1.0, "Weight of the bone-length constancy term.")
    accel_sigma_m_s2: float = setting(
        40.0,
        "Typical joint acceleration (m/s^2); divides second differences (times fps^2) in the "
        "smoothness term. Smaller is smoother; a punch peaks near 100 m/s^2.",
    )
    smoothness_weight: float = setting(1.0, "Weight of the temporal smoothness term.")
    root_accel_sigma_m_s2: float = setting(
        10.0,
        "Typical acceleration (m/s^2) of the hip centre, which carries the whole body and so "
        "moves more smoothly than the limbs; its own smoothness term steadies the depth, which "
        "the image fixes least.",
    )
    floor_sigma_m: float = setting(
        0.01,
        "Tolerance (m) of a contact foot's lowest sole point about the floor and of any sole "
        "point below it.",
    )
    slide_sigma_m: float = setting(
        0.003, "Tolerance (m per frame) of a contact foot's horizontal slide in the lift."
    )
    contact_weight: float = setting(1.0, "Weight of the feet-on-floor terms in the lift.")
    init_smooth_sigma_frames: float = setting(
        1.5,
        "Gaussian sigma (frames) of the temporal filter on the lift's starting point, which "
        "saves iterations; 0 starts from the raw landmarks.",
    )
    iterations: int = setting(
        80, "L-BFGS iterations of the lift before contacts are detected (fp32, all frames)."
    )
    contact_iterations: int = setting(
        40, "L-BFGS iterations of the lift after contact detection, with the floor terms."
    )
    contact_height_m: float = setting(
        0.05, "A foot is in contact when its lowest sole point is below this height (m) ..."
    )
    contact_speed_m_s: float = setting(
        0.6, "... and its sole's midpoint moves horizontally slower than this (m/s)."
    )
    floor_settle_s: float = setting(
        0.5,
        "A fighter whose lowest point stays above the floor longer than this (s) is lowered "
        "onto it in the cleanup (a hop shorter than this keeps its flight); 0 turns it off.",
    )
    contact_min_frames: int = setting(
        3, "Contact runs shorter than this many frames are dropped, and gaps shorter are filled."
    )
    ik_iterations: int = setting(
        15, "Levenberg-Marquardt iterations of the humanoid fit (batched over all frames)."
    )
    ik_damping: float = setting(
        1e-3, "Initial Levenberg-Marquardt damping, relative to the normal matrix's diagonal."
    )
    ik_face_weight: float = setting(
        0.3, "IK weight of the face landmarks relative to the body's (1)."
    )
    smooth_sigma_frames: float = setting(
        1.0, "Gaussian sigma (frames) of the zero-phase jitter filter on qpos; 0 turns it off."
    )
    root_follow_sigma_frames: float = setting(
        4.0,
        "Gaussian sigma (frames) of the root's correction that follows the contact feet onto "
        "their anchors and the floor, before leg IK takes out the rest.",
    )
    contact_blend_frames: int = setting(
        4, "Frames over which a contact foot's correction fades in before and out after contact."
    )
    cleanup_ik_iterations: int = setting(
        8, "Levenberg-Marquardt iterations of the leg IK that pins contact feet."
    )
    separation_margin_m: float = setting(
        0.01, "Clearance (m) kept between the two fighters' geoms when pushing them apart."
    )
    separation_share: float = setting(
        0.5,
        "Share (0-1) of a separation between two fighters that the first one cleaned makes "
        "(cleanup_pair); the second makes the rest.",
    )
    separation_smooth_frames: int = setting(
        5, "Half-width (frames) of the max-then-mean filter that smooths separation offsets."
    )

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"LiftConfig.{f.name} must be a number, got {value!r}")
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"LiftConfig.{f.name} must be finite and >= 0, got {value!r}")
        for name in (
            "reprojection_sigma_px",
            "shape_sigma_m",
            "bone_sigma_m",
            "accel_sigma_m_s2",
            "floor_sigma_m",
            "slide_sigma_m",
            "root_accel_sigma_m_s2",
            "contact_height_m",
            "contact_speed_m_s",
        ):
            if getattr(self, name) <= 0:
                raise ValueError(f"LiftConfig.{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("min_confidence", "separation_share"):
            if getattr(self, name) > 1:
                raise ValueError(f"LiftConfig.{name} must be in [0, 1], got {getattr(self, name)}")


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
    adversary_height_m: float = setting(
        0.0,
        "The adversary's standing height (m, from the tale of the tape; 0 = unknown): his "
        "lifted body is scaled to it, and with it the scene and the camera's height. Where one "
        "fighter's height is known and the other's is not, the other is scaled to stand on the "
        "same floor; where neither is, the scale is BlazePose's average body's.",
    )
    opponent_height_m: float = setting(
        0.0, "The opponent's standing height (m; 0 = unknown), as adversary_height_m."
    )
    solve: LiftConfig = field(default_factory=LiftConfig)
    gates: GateConfig = field(default_factory=GateConfig)

    def __post_init__(self) -> None:
        if not 1.0 < self.fov_deg < 179.0:
            raise ValueError(f"lift.fov_deg must be in (1, 179), got {self.fov_deg}")
        if self.min_frames < 3:
            raise ValueError(f"lift.min_frames must be at least 3, got {self.min_frames}")
        for name in ("adversary_height_m", "opponent_height_m"):
            value = getattr(self, name)
            if value != 0 and not MIN_STATURE_M <= value <= MAX_STATURE_M:
                raise ValueError(
                    f"lift.{name} must be 0 (unknown) or a standing height in metres between "
                    f"{MIN_STATURE_M} and {MAX_STATURE_M}, got {value}"
                )

    def statures(self) -> dict[str, float | None]:
        """Each role's known standing height (m), None where unknown."""
        return {
            "adversary": self.adversary_height_m or None,
            "opponent": self.opponent_height_m or None,
        }
