"""Pose backends: people detectors and 2D/3D pose estimators behind one interface.

The interface lives in `models.pose.types`; the default backend (BlazePose on
LiteRT) in `models.pose.blazepose`, imported from there so that using the types
does not load a model runtime.
"""

from models.pose.types import COCO_17, Detection, Detector, Pose, PoseEstimator

__all__ = ["COCO_17", "Detection", "Detector", "Pose", "PoseEstimator"]
