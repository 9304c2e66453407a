"""The pose stage's config."""

from __future__ import annotations

from dataclasses import dataclass, field

from models.settings import setting
from tasks.pose.fighters import FighterConfig
from tasks.pose.refine import RefineConfig
from tasks.pose.tracking import TrackerConfig

BACKENDS = ("blazepose", "onnx")


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
        "Run the person detector every N frames; in between, people are followed from their last "
        "pose. Frames with nobody followed are always searched.",
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
    num_threads: int = setting(2, "CPU threads per model.")
    workers: int = setting(1, "Chunks processed at the same time (threads).")
    overlap_frames: int = setting(
        8, "Frames a chunk re-reads before its start, to join its tracks to the previous chunk's."
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
        "note (metric fighter_choice_margin: 1 with a single candidate pair).",
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
            "min_fighter_share",
            "min_together_share",
            "min_choice_margin",
        ):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"pose.{name} must be in [0, 1], got {getattr(self, name)}")
        if self.backend == "onnx" and not (self.detector_model and self.pose_model):
            raise ValueError("pose.backend 'onnx' needs pose.detector_model and pose.pose_model")
