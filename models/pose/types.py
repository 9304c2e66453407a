"""The pose-backend interface: what a detector and a pose estimator return.

Every backend (BlazePose on LiteRT, the ONNX RTMDet/RTMPose pair) speaks these
types, so the pose stage, the tracker and the tests never depend on which one
runs. Coordinates are image pixels, x right and y down, as floats.

Shape letters: K detector keypoints, J pose joints (33 for BlazePose).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

# BlazePose's 33 landmarks, in the model's output order.
BLAZEPOSE_33: tuple[str, ...] = (
    "nose",
    "left_eye_inner",
    "left_eye",
    "left_eye_outer",
    "right_eye_inner",
    "right_eye",
    "right_eye_outer",
    "left_ear",
    "right_ear",
    "mouth_left",
    "mouth_right",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_pinky",
    "right_pinky",
    "left_index",
    "right_index",
    "left_thumb",
    "right_thumb",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
    "left_heel",
    "right_heel",
    "left_foot_index",
    "right_foot_index",
)

# The 17 COCO keypoints, in COCO order.
COCO_17: tuple[str, ...] = (
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
)

# Index into the BlazePose 33 of each COCO point; every COCO joint has a
# same-named BlazePose landmark, so the map is a plain selection.
BLAZEPOSE_TO_COCO17: np.ndarray = np.array([BLAZEPOSE_33.index(name) for name in COCO_17])


def _check_array(name: str, value: np.ndarray, shape: tuple[int | None, ...]) -> None:
    """Raise ValueError naming `name` unless `value` has `shape` (None = any)."""
    ok = value.ndim == len(shape) and all(
        s is None or s == v for s, v in zip(shape, value.shape, strict=True)
    )
    if not ok:
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name} must have shape {want}, got {value.shape}")


# eq=False: fields are arrays, whose == is elementwise; compare by identity.
@dataclass(frozen=True, eq=False)
class Detection:
    """One person found by a detector.

    Attributes:
        box: (4,) float person box x0, y0, x1, y1 in image pixels.
        score: detector confidence in 0..1.
        keypoints: optional (K, 2) float keypoints in image pixels; the
            BlazePose detector gives K=4 alignment points (hip centre, full-body
            scale point, shoulder centre, upper-body scale point).
    """

    box: np.ndarray
    score: float
    keypoints: np.ndarray | None = None

    def __post_init__(self) -> None:
        _check_array("Detection.box", np.asarray(self.box), (4,))
        if self.keypoints is not None:
            _check_array("Detection.keypoints", np.asarray(self.keypoints), (None, 2))


@dataclass(frozen=True, eq=False)
class Pose:
    """2D (and optionally 3D) pose of one person.

    Attributes:
        keypoints: (J, 2) float joint positions in image pixels.
        confidence: (J,) per-joint confidence in 0..1 (for BlazePose the
            landmark's visibility: the chance it is in frame and not occluded).
        world: optional (J, 3) metric joint positions in metres, origin between
            the hips, x and y along the image's x (right) and y (down), smaller z
            nearer the camera (BlazePose world landmarks).
        presence: optional (J,) chance each joint lies inside the image.
        score: chance the crop holds a person at all (BlazePose's pose flag).
        alignment: optional (2, 2) hip centre and full-body scale point in
            pixels (BlazePose's auxiliary landmarks): where to crop this person
            in the next frame.
    """

    keypoints: np.ndarray
    confidence: np.ndarray
    world: np.ndarray | None = None
    presence: np.ndarray | None = None
    score: float = 1.0
    alignment: np.ndarray | None = None

    def __post_init__(self) -> None:
        keypoints = np.asarray(self.keypoints)
        _check_array("Pose.keypoints", keypoints, (None, 2))
        num_joints = keypoints.shape[0]
        _check_array("Pose.confidence", np.asarray(self.confidence), (num_joints,))
        if self.world is not None:
            _check_array("Pose.world", np.asarray(self.world), (num_joints, 3))
        if self.presence is not None:
            _check_array("Pose.presence", np.asarray(self.presence), (num_joints,))
        if self.alignment is not None:
            _check_array("Pose.alignment", np.asarray(self.alignment), (2, 2))

    def coco17(self) -> tuple[np.ndarray, np.ndarray]:
        """The COCO-17 subset: (17, 2) keypoints in pixels and (17,) confidences.

        Only defined for 33-landmark BlazePose poses; raises ValueError otherwise.
        """
        if len(self.keypoints) != len(BLAZEPOSE_33):
            raise ValueError(
                f"Pose.coco17 needs {len(BLAZEPOSE_33)} BlazePose keypoints, "
                f"got {len(self.keypoints)}"
            )
        index = BLAZEPOSE_TO_COCO17
        return np.asarray(self.keypoints)[index].copy(), np.asarray(self.confidence)[index].copy()

    def bbox(self, *, min_confidence: float = 0.0) -> np.ndarray:
        """(4,) x0, y0, x1, y1 box around the joints with confidence >= min_confidence.

        The default takes every joint: BlazePose still places occluded joints,
        only at low visibility, and dropping them can cut a person's legs off
        the box. Falls back to all joints when none is confident enough.
        """
        keypoints = np.asarray(self.keypoints, dtype=np.float64)
        confident = np.asarray(self.confidence) >= min_confidence
        points = keypoints[confident] if confident.any() else keypoints
        return np.concatenate([points.min(axis=0), points.max(axis=0)])


class Detector(Protocol):
    """Finds people in one frame."""

    def __call__(self, image_bgr: np.ndarray) -> list[Detection]:
        """image_bgr: (H, W, 3) uint8 BGR frame. Returns detections, best first."""
        ...


class PoseEstimator(Protocol):
    """Estimates one person's pose from a frame and where that person is."""

    def __call__(self, image_bgr: np.ndarray, box: Detection | Pose | np.ndarray) -> Pose:
        """image_bgr: (H, W, 3) uint8 BGR frame; box: the person's Detection, their
        Pose in the previous frame (to follow them), or a (4,) x0, y0, x1, y1
        person box in pixels (e.g. a tracker's prediction)."""
        ...
