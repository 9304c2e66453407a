"""The pose stage's config."""

from __future__ import annotations

from dataclasses import dataclass, field

from models.settings import setting
from tasks.pose.checks import check_window

BACKENDS = ("blazepose", "onnx")
# The smoothers refinement can apply last (`tasks.pose.refine.SMOOTHERS`).
SMOOTHER_NAMES = ("none", "one_euro", "savitzky_golay", "confidence_weighted", "adaptive_window")


@dataclass(frozen=True)
class RefineConfig:
    """How one fighter's 2D keypoints are refined over a chunk of frames.

    Smoother parameters are the picks of ``benchmarks/refine_filters.py --sweep`` on the
    synthetic fighter (about 400 px tall, 30 fps); pixel- and frame-based ones want revisiting
    for much smaller fighters or other frame rates.
    """

    smoother: str = setting(
        "adaptive_window",
        "Smoother applied last, a name in SMOOTHERS: none, one_euro, savitzky_golay, "
        "confidence_weighted, adaptive_window (the winner of benchmarks/refine_filters.py).",
    )
    min_confidence: float = setting(
        0.3,
        "Joint confidence (0-1) below which a point is untrusted: it neither votes on flips nor "
        "survives gap filling (replaced when the gap is short, else NaN).",
    )
    max_gap: int = setting(
        5, "Longest run of missing or untrusted frames (per joint) that is interpolated."
    )
    flip_ratio: float = setting(
        0.5,
        "A limb group's left/right labels are swapped back when its mirrored cost against the "
        "previous frames is below this share of its as-is cost.",
    )
    flip_max_age: int = setting(
        10, "Frames after which a joint's last position no longer serves as a flip reference."
    )
    one_euro_min_cutoff: float = setting(2.0, "1€ filter cutoff at rest (Hz).")
    one_euro_beta: float = setting(
        0.1,
        "1€ filter cutoff gain per unit speed (Hz per px/s); in pixels, so it suits fighters "
        "about 400 px tall and wants scaling with their size.",
    )
    one_euro_d_cutoff: float = setting(5.0, "1€ filter cutoff of its speed estimate (Hz).")
    sg_window: int = setting(7, "Savitzky-Golay window (odd, frames).")
    sg_order: int = setting(2, "Savitzky-Golay polynomial degree.")
    cw_window: int = setting(7, "Confidence-weighted regression window (odd, frames).")
    cw_order: int = setting(2, "Confidence-weighted regression polynomial degree.")
    cw_robust_iterations: int = setting(
        1, "Rounds of outlier reweighting in the confidence-weighted regression (0 = none)."
    )
    ici_window_min: int = setting(5, "Adaptive-window regression: shortest window (odd, frames).")
    ici_window_max: int = setting(
        17, "Adaptive-window regression: longest window at most this many frames."
    )
    ici_window_step: int = setting(
        4, "Adaptive-window regression: growth from one window to the next (even, frames)."
    )
    ici_order: int = setting(2, "Adaptive-window regression polynomial degree.")
    ici_threshold: float = setting(
        1.0,
        "Adaptive-window regression: confidence-interval half-width in noise standard "
        "deviations; larger keeps longer windows (smoother, more peak clipping).",
    )
    ici_robust_iterations: int = setting(
        1, "Rounds of outlier reweighting in the adaptive-window regression (0 = none)."
    )

    @property
    def ici_windows(self) -> tuple[int, ...]:
        """The adaptive-window regression's window lengths, shortest first."""
        return tuple(range(self.ici_window_min, self.ici_window_max + 1, self.ici_window_step))

    def __post_init__(self) -> None:
        if self.smoother not in SMOOTHER_NAMES:
            raise ValueError(
                f"refine.smoother must be one of {sorted(SMOOTHER_NAMES)}, got {self.smoother!r}"
            )
        if not 0.0 <= self.min_confidence <= 1.0:
            raise ValueError(f"refine.min_confidence must be in [0, 1], got {self.min_confidence}")
        for name in ("max_gap", "cw_robust_iterations", "ici_robust_iterations"):
            if getattr(self, name) < 0:
                raise ValueError(f"refine.{name} must be >= 0, got {getattr(self, name)}")
        if self.flip_max_age < 1:
            raise ValueError(f"refine.flip_max_age must be >= 1, got {self.flip_max_age}")
        for name in ("flip_ratio", "one_euro_min_cutoff", "one_euro_d_cutoff", "ici_threshold"):
            if not getattr(self, name) > 0:
                raise ValueError(f"refine.{name} must be > 0, got {getattr(self, name)}")
        if self.one_euro_beta < 0:
            raise ValueError(f"refine.one_euro_beta must be >= 0, got {self.one_euro_beta}")
        check_window(
            "refine.sg_window", self.sg_window, self.sg_order, order_name="refine.sg_order"
        )
        check_window(
            "refine.cw_window", self.cw_window, self.cw_order, order_name="refine.cw_order"
        )
        if self.cw_window < 2 * self.cw_order + 1:
            raise ValueError(
                f"refine.cw_window must be at least 2 * refine.cw_order + 1, got {self.cw_window}"
            )
        if self.ici_window_step < 2 or self.ici_window_step % 2:
            raise ValueError(
                f"refine.ici_window_step must be a positive even number, got {self.ici_window_step}"
            )
        if self.ici_window_max < self.ici_window_min:
            raise ValueError(
                f"refine.ici_window_max ({self.ici_window_max}) must be at least "
                f"refine.ici_window_min ({self.ici_window_min})"
            )
        check_window(
            "refine.ici_window_min",
            self.ici_window_min,
            self.ici_order,
            order_name="refine.ici_order",
        )
        if self.ici_window_min < 2 * self.ici_order + 1:
            raise ValueError(
                "refine.ici_window_min must be at least 2 * refine.ici_order + 1, "
                f"got {self.ici_window_min}"
            )


@dataclass(frozen=True)
class TrackerConfig:
    """How detections are linked into tracks across frames."""

    alpha: float = setting(
        0.5,
        "Weight of the position distance d_s against the clothing-colour distance d_c in the "
        "association cost alpha * d_s + (1 - alpha) * d_c (boxing pose thesis); both lie in "
        "[0, 1].",
    )
    gate_distance: float = setting(
        0.4,
        "Largest distance, in heights of the predicted box, between a track's predicted centre "
        "and an observation's centre for them to be matched; d_s is the distance over this.",
    )
    gate_growth_per_s: float = setting(
        4.0,
        "How fast the position gate widens while a track coasts unseen, as a share of "
        "gate_distance per second: a prediction made blind drifts.",
    )
    max_colour_distance: float = setting(
        0.8,
        "Largest clothing-colour distance (0-1) at which an observation may join a track.",
    )
    max_cost: float = setting(
        0.4,
        "Largest association cost (0-1) at which an observation may join a track; above it the "
        "observation is better left to start a new track and the track to coast.",
    )
    max_height_ratio: float = setting(
        2.0,
        "An observation whose box height differs from the predicted one by more than this "
        "factor, up or down, cannot join the track (a small spectator is not a fighter).",
    )
    max_coast_s: float = setting(
        1.0,
        "Seconds a confirmed track may go unseen (occluded, missed) and still keep its id; "
        "after that it ends.",
    )
    min_hits: int = setting(
        3,
        "Consecutive frames a new track must be observed before it is confirmed and given an "
        "id (tracks seen in the first frame of a shot are confirmed at once).",
    )
    colour_rate: float = setting(
        0.1,
        "Rate of the exponential moving average that updates a track's colour descriptor from "
        "each clean (unoccluded) observation.",
    )
    occlusion_overlap: float = setting(
        0.3,
        "An observation whose box is covered by another observation's box over more than this "
        "share of its area is partly someone else: it does not update the track's colour.",
    )
    high_score: float = setting(
        0.5,
        "Detections scoring at least this are matched first, to every track (ByteTrack).",
    )
    low_score: float = setting(
        0.1,
        "Detections scoring in [low_score, high_score) are matched second, only to confirmed "
        "tracks left over (often a person half hidden); below low_score they are ignored.",
    )
    new_track_score: float = setting(
        0.6, "Least score of an unmatched detection for it to start a new track."
    )
    duplicate_iou: float = setting(
        0.7,
        "An unmatched detection overlapping an already used one by more than this IoU is a "
        "duplicate of it and starts no track.",
    )
    same_body_iou: float = setting(
        0.7,
        "Two observations whose boxes overlap by more than this IoU and whose keypoints lie "
        "within same_body_gap of each other are one body seen twice (two followed poses that "
        "slid onto one person in an overlap): only the track whose motion and colour fit it "
        "best keeps it, the other coasts until its own person is found again.",
    )
    same_body_gap: float = setting(
        0.05,
        "Median keypoint distance, as a share of the box height, under which two overlapping "
        "observations are one body (see same_body_iou).",
    )
    position_noise: float = setting(
        1 / 20,
        "Kalman standard deviation of box position and size, as a share of box size per frame "
        "(DeepSORT's value).",
    )
    velocity_noise: float = setting(
        1 / 160,
        "Kalman standard deviation of box velocity, as a share of box size per frame "
        "(DeepSORT's value).",
    )

    def __post_init__(self) -> None:
        unit = ("alpha", "max_colour_distance", "max_cost", "colour_rate", "occlusion_overlap")
        unit += ("high_score", "low_score", "new_track_score", "duplicate_iou", "same_body_iou")
        unit += ("same_body_gap",)
        for name in unit:
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"tracker.{name} must be in [0, 1], got {getattr(self, name)}")
        for name in ("gate_distance", "position_noise", "velocity_noise"):
            if not getattr(self, name) > 0:
                raise ValueError(f"tracker.{name} must be positive, got {getattr(self, name)}")
        for name in ("gate_growth_per_s", "max_coast_s"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"tracker.{name} must be >= 0, got {getattr(self, name)}")
        if not self.max_height_ratio >= 1.0:
            raise ValueError(f"tracker.max_height_ratio must be >= 1, got {self.max_height_ratio}")
        if self.min_hits < 1:
            raise ValueError(f"tracker.min_hits must be at least 1, got {self.min_hits}")
        if self.low_score > self.high_score:
            raise ValueError(
                f"tracker.low_score ({self.low_score}) must not exceed "
                f"tracker.high_score ({self.high_score})"
            )


@dataclass(frozen=True)
class FighterConfig:
    """Weights of the terms that score tracks and pairs of tracks as the two fighters.

    Every term lies in [0, 1]; a track's score is the weighted mean of its terms, a pair's score
    is the mean of its two track scores plus the weighted mean of the pair terms.
    """

    presence_weight: float = setting(
        1.0,
        "Weight of presence: the share of the span's frames in which the track is observed "
        "(fighters are in view nearly all the time, passers-by are not).",
    )
    size_weight: float = setting(
        1.0,
        "Weight of size: the track's mean box height over the tallest track's (the camera "
        "frames the fighters; the crowd is small and far).",
    )
    centre_weight: float = setting(
        1.0,
        "Weight of centrality: 1 at the frame's centre, 0 at its edge, from the track's mean "
        "centre (the crowd sits at the edges).",
    )
    similar_size_weight: float = setting(
        0.5, "Weight of the pair's similarity in size: smaller mean height over larger."
    )
    together_weight: float = setting(
        0.5, "Weight of the share of the span's frames in which both tracks are observed."
    )
    near_weight: float = setting(
        0.5,
        "Weight of nearness: 1 - (mean centre distance while both are seen) / (near_scale x "
        "mean height), floored at 0 (fighters stay within reach of each other).",
    )
    near_scale: float = setting(
        2.0, "Distance, in mean box heights, at which the nearness term falls to 0."
    )

    def __post_init__(self) -> None:
        for name in (
            "presence_weight",
            "size_weight",
            "centre_weight",
            "similar_size_weight",
            "together_weight",
            "near_weight",
        ):
            if not getattr(self, name) >= 0:
                raise ValueError(f"fighters.{name} must be >= 0, got {getattr(self, name)}")
        if self.presence_weight + self.size_weight + self.centre_weight <= 0:
            raise ValueError("fighters: presence, size and centre weights must not all be 0")
        if not self.near_scale > 0:
            raise ValueError(f"fighters.near_scale must be positive, got {self.near_scale}")


@dataclass(frozen=True)
class PoseConfig:
    """How people are found, followed and estimated, and how the fighters are chosen."""

    backend: str = setting(
        "blazepose",
        "Pose backend: 'blazepose' (BlazePose weights from `ringside assets pull`, on LiteRT) "
        "or 'onnx' (your own RTMDet/YOLOX detector and RTMPose model files).",
    )
    detector_model: str = setting(
        "", "Detector model file; empty takes the backend's default (BlazePose: the pulled asset)."
    )
    pose_model: str = setting(
        "",
        "Pose model file; empty takes the backend's default (BlazePose: the pulled "
        "pose_landmark_full.tflite). The pulled pose_landmark_heavy.tflite is slower "
        "(benchmarks/pose_speed.py); on the sample's multi-view benchmark it lifted the man "
        "3 mm closer to the reference and the woman 6 mm further (benchmarks/lift_multiview.py).",
    )
    detect_every: int = setting(
        3,
        "Run the person detector on every frame whose index is a multiple of N, and estimate "
        "everyone it finds in the crop of their detection; in between, people are followed "
        "from their last pose. Frames with nobody followed are always searched.",
    )
    detector_tiles: int = setting(
        2,
        "Square tiles (the frame's short side) the detector runs on, spread along the long side; "
        "1 runs it once on the whole frame. Small people are found far more often on tiles.",
    )
    detection_score: float = setting(0.5, "Detections scoring below this (0-1) are dropped.")
    pose_score: float = setting(
        0.5, "A pose whose person-present score is below this (0-1) counts as not seen."
    )
    redetect_iou: float = setting(
        0.3,
        "A detection overlapping someone already followed by more than this IoU is the same "
        "person and is not estimated again.",
    )
    anchor_distance: float = setting(
        0.1,
        "A followed person is estimated again in the crop of their detection only if the pose "
        "found there lies within this share of their height (median over the joints) of their "
        "last pose; otherwise (the crop held someone else, or part of them) they are followed "
        "on from their last pose.",
    )
    num_threads: int = setting(2, "CPU threads per model.")
    workers: int = setting(1, "Chunks processed at the same time (threads).")
    overlap_frames: int = setting(
        8,
        "Frames a chunk re-reads before its start, to join its tracks to the previous chunk's; "
        "at least `detect_every`, so that its keypoints are those of one long chunk.",
    )
    min_fighter_share: float = setting(
        0.2, "A track seen in less than this share of its shot's frames is never a fighter."
    )
    min_together_share: float = setting(
        0.5,
        "A shot whose chosen fighters are seen together in less than this share of its frames "
        "gets a note (a crowd, one person, passers-by: perhaps not two people fighting), naming "
        "the next candidate pairs for `ringside pick`.",
    )
    min_choice_margin: float = setting(
        0.1,
        "A shot whose chosen pair scores less than this share above the next pair gets the same "
        "note (metric fighter_choice_margin; a shot with a single candidate pair has no margin "
        "and is left out of it).",
    )
    link_gap_s: float = setting(
        2.0,
        "Tracks of one shot that end and start again within this many seconds, near where the "
        "first was heading and dressed alike, are joined as one person before fighters are "
        "chosen (occlusions longer than the tracker survives).",
    )
    overlay_seconds: float = setting(
        20.0,
        "Seconds of the review overlay video, from where the fighters are first seen (0: the "
        "whole video).",
    )
    overlay_max_side: int = setting(960, "Long side (pixels) of the review overlay video.")
    stills: int = setting(4, "PNG stills of the overlay, spread over the video.")
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    fighters: FighterConfig = field(default_factory=FighterConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise ValueError(f"pose.backend must be one of {BACKENDS}, got {self.backend!r}")
        for name in (
            "detect_every",
            "detector_tiles",
            "num_threads",
            "workers",
            "overlay_max_side",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"pose.{name} must be at least 1, got {getattr(self, name)}")
        if self.link_gap_s < 0:
            raise ValueError(f"pose.link_gap_s must be at least 0, got {self.link_gap_s}")
        for name in ("overlap_frames", "stills"):
            if getattr(self, name) < 0:
                raise ValueError(f"pose.{name} must be at least 0, got {getattr(self, name)}")
        for name in (
            "detection_score",
            "pose_score",
            "redetect_iou",
            "anchor_distance",
            "min_fighter_share",
            "min_together_share",
            "min_choice_margin",
        ):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"pose.{name} must be in [0, 1], got {getattr(self, name)}")
        if self.overlap_frames < self.detect_every:
            raise ValueError(
                f"pose.overlap_frames ({self.overlap_frames}) must be at least pose.detect_every "
                f"({self.detect_every}): a chunk's keypoints would depend on where it starts"
            )
        if self.backend == "onnx" and not (self.detector_model and self.pose_model):
            raise ValueError("pose.backend 'onnx' needs pose.detector_model and pose.pose_model")
