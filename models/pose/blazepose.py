"""BlazePose person detector and 33-landmark pose model, run with LiteRT.

Bazarevsky et al., "BlazePose: On-device Real-time Body Pose tracking",
CVPR Workshops 2020. The weights are the `pose_detection.tflite` and
`pose_landmark_full.tflite` files of the mediapipe 0.10.21 wheel (Apache-2.0);
everything around the two networks (anchors, decoding, NMS, region of interest,
crop warp, landmark projection) is here, as pure NumPy functions.

How the two models fit together:
1. The detector sees the whole frame letterboxed to 224x224. Each of its 2254
   SSD anchors scores a person (the face is its main cue), places a box near
   the head and 4 alignment keypoints: hip centre, a point whose distance
   from it is the radius of a circle holding the whole body, shoulder centre,
   and the same for the upper body. The box's size is the same for every
   anchor, so the person box is built from the keypoints (`person_box`).
2. The landmark model sees a 256x256 crop: the square around that circle,
   scaled by 1.25 and rotated so the body stands upright. It returns 39
   landmarks (33 body points and 6 auxiliary ones) in crop pixels, with
   visibility and presence logits, a pose-presence probability, and 39
   world landmarks in metres.

Coordinates are image pixels (x right, y down) unless a name says otherwise.
Shape letters: N anchors, M detections after NMS, K detector keypoints (4),
J landmarks.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from ai_edge_litert.interpreter import Interpreter

from models.pose.boxes import Letterbox, box_iou, check_image, letterbox
from models.pose.types import Detection, Pose

# Detector (pose_detection.tflite).
DETECTOR_INPUT_SIZE = 224
DETECTOR_STRIDES = (8, 16, 32, 32, 32)
DETECTOR_ANCHORS_PER_LAYER = 2
DETECTOR_ANCHOR_OFFSET = 0.5
DETECTOR_NUM_ANCHORS = 2254
DETECTOR_NUM_KEYPOINTS = 4
# Alignment keypoints of the detector.
HIP_CENTER = 0
FULL_BODY_SCALE_POINT = 1

# Landmark model (pose_landmark_full.tflite).
LANDMARKER_INPUT_SIZE = 256
LANDMARKER_NUM_OUTPUT_LANDMARKS = 39  # 33 body points + 6 auxiliary
NUM_BODY_LANDMARKS = 33

# Auxiliary landmarks the model predicts for following a person to the next
# frame: the hip centre and the full-body scale point, as the detector gives.
AUX_HIP_CENTER = 33
AUX_SCALE_POINT = 34

# The landmark model expects crops 1.25x the alignment circle's square (the
# scale of the graphs it ships with).
ROI_SCALE = 1.25

# Logits beyond this saturate the sigmoid; clipping avoids exp overflow warnings.
_LOGIT_CLIP = 80.0


def sigmoid(x: np.ndarray) -> np.ndarray:
    """Elementwise logistic function, safe for large |x|."""
    return 1.0 / (1.0 + np.exp(-np.clip(x, -_LOGIT_CLIP, _LOGIT_CLIP)))


# --------------------------------------------------------------------------
# Detector helpers
# --------------------------------------------------------------------------


def ssd_anchors(
    input_size: int = DETECTOR_INPUT_SIZE,
    strides: tuple[int, ...] = DETECTOR_STRIDES,
    *,
    anchors_per_layer: int = DETECTOR_ANCHORS_PER_LAYER,
    offset: float = DETECTOR_ANCHOR_OFFSET,
) -> np.ndarray:
    """Centres of the detector's SSD anchors, in the order of its outputs.

    The anchors have a fixed size (the whole input), so a centre is all an
    anchor holds. Consecutive layers with the same stride share one feature
    map, which then carries all their anchors at each location: for the
    pose detector, 28x28x2 + 14x14x2 + 7x7x6 = 2254.

    Returns:
        (N, 2) float anchor centres (x, y), normalised to the input (0..1).
    """
    if input_size <= 0:
        raise ValueError(f"input_size must be positive, got {input_size}")
    if not strides or any(s <= 0 for s in strides):
        raise ValueError(f"strides must be a non-empty tuple of positive ints, got {strides}")
    centres = []
    start = 0
    while start < len(strides):
        stop = start
        while stop < len(strides) and strides[stop] == strides[start]:
            stop += 1
        side = math.ceil(input_size / strides[start])
        ys, xs = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
        grid = np.stack([(xs + offset) / side, (ys + offset) / side], axis=-1).reshape(-1, 2)
        # Order within the output: row, column, then anchor at that location.
        centres.append(np.repeat(grid, anchors_per_layer * (stop - start), axis=0))
        start = stop
    return np.concatenate(centres).astype(np.float32)


def decode_detections(
    raw_boxes: np.ndarray,
    raw_scores: np.ndarray,
    anchors: np.ndarray,
    input_size: int = DETECTOR_INPUT_SIZE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Turn the detector's raw regressions into boxes, keypoints and scores.

    Each regression is an offset in input pixels from its anchor's centre
    (fixed-size anchors, so no scaling by anchor size).

    Args:
        raw_boxes: (N, 4 + 2K) cx, cy, w, h, then K (x, y) keypoints.
        raw_scores: (N,) or (N, 1) score logits.
        anchors: (N, 2) anchor centres, normalised (see `ssd_anchors`).
        input_size: side of the square detector input, in pixels.

    Returns:
        boxes (N, 4) x0, y0, x1, y1; keypoints (N, K, 2); scores (N,) in 0..1.
        Boxes and keypoints are normalised to the input (0..1).
    """
    raw_boxes = np.asarray(raw_boxes, dtype=np.float32)
    raw_scores = np.asarray(raw_scores, dtype=np.float32).reshape(-1)
    if raw_boxes.ndim != 2 or raw_boxes.shape[1] < 4 or raw_boxes.shape[1] % 2:
        raise ValueError(f"raw_boxes must have shape (N, 4 + 2K), got {raw_boxes.shape}")
    if len(raw_scores) != len(raw_boxes) or anchors.shape != (len(raw_boxes), 2):
        raise ValueError(
            f"raw_scores {raw_scores.shape} and anchors {anchors.shape} must match "
            f"raw_boxes {raw_boxes.shape} in N"
        )
    scaled = raw_boxes / input_size
    centre = scaled[:, 0:2] + anchors
    half = scaled[:, 2:4] / 2
    boxes = np.concatenate([centre - half, centre + half], axis=1)
    keypoints = scaled[:, 4:].reshape(len(raw_boxes), -1, 2) + anchors[:, None, :]
    return boxes, keypoints, sigmoid(raw_scores)


def weighted_nms(
    boxes: np.ndarray,
    scores: np.ndarray,
    keypoints: np.ndarray,
    iou_threshold: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Non-maximum suppression that averages each cluster instead of keeping one box.

    Neighbouring anchors all fire on the same person, each slightly off; the
    score-weighted mean of a cluster is steadier from frame to frame than its
    single best member (the blending of Bazarevsky et al., "BlazeFace", 2019).

    Args:
        boxes: (M, 4) x0, y0, x1, y1.
        scores: (M,).
        keypoints: (M, K, 2).
        iou_threshold: boxes with IoU above this with the cluster's best join it.

    Returns:
        boxes (M', 4), scores (M',) (each cluster's best score), keypoints
        (M', K, 2); best first.
    """
    order = np.argsort(-np.asarray(scores), kind="stable")
    out_boxes, out_scores, out_keypoints = [], [], []
    while len(order):
        best = order[0]
        in_cluster = box_iou(boxes[best], boxes[order]) > iou_threshold
        in_cluster[0] = True  # a degenerate (zero-area) best box still counts itself
        members = order[in_cluster]
        weights = scores[members] / scores[members].sum()
        out_boxes.append(weights @ boxes[members])
        out_keypoints.append(np.tensordot(weights, keypoints[members], axes=1))
        out_scores.append(scores[best])
        order = order[~in_cluster]
    num_keypoints = keypoints.shape[1] if keypoints.ndim == 3 else 0
    if not out_boxes:
        return np.zeros((0, 4)), np.zeros(0), np.zeros((0, num_keypoints, 2))
    return np.array(out_boxes), np.array(out_scores), np.array(out_keypoints)


# Extent of a person around the hip centre, in units of the alignment radius r
# (hip centre to full-body scale point). The circle of radius r holds the whole
# body with margin; on the multi-person sample the confident landmarks reached
# 0.6-1.0r from the hip centre along the body axis and spanned 0.5-0.85r across
# it, so 0.9r and 0.4r either side give a box that holds most poses.
PERSON_HALF_LENGTH = 0.9
PERSON_HALF_WIDTH = 0.4


def person_box(keypoints: np.ndarray) -> np.ndarray:
    """A whole-body box for a tracker, from BlazePose's alignment keypoints.

    The detector's own box output is useless as a box (its size is the same
    ~45 input pixels for every anchor), so the box comes from the alignment
    keypoints instead: PERSON_HALF_LENGTH * r either side of the hip centre
    along the body axis and PERSON_HALF_WIDTH * r across it, rotated with the
    body and made axis-aligned.

    Args:
        keypoints: (K >= 2, 2) detector keypoints in pixels; 0 = hip centre,
            1 = full-body scale point.

    Returns:
        (4,) x0, y0, x1, y1 in pixels (not clipped to the image).
    """
    keypoints = np.asarray(keypoints, dtype=np.float64)
    if keypoints.ndim != 2 or keypoints.shape[1] != 2 or len(keypoints) < 2:
        raise ValueError(f"keypoints must have shape (K >= 2, 2), got {keypoints.shape}")
    hip = keypoints[HIP_CENTER]
    axis = keypoints[FULL_BODY_SCALE_POINT] - hip
    radius = float(np.hypot(*axis))
    up = axis / radius if radius > 0 else np.array([0.0, -1.0])
    across = np.array([-up[1], up[0]])
    half_extent = (
        np.abs(up) * PERSON_HALF_LENGTH * radius + np.abs(across) * PERSON_HALF_WIDTH * radius
    )
    return np.concatenate([hip - half_extent, hip + half_extent])


# --------------------------------------------------------------------------
# Region of interest and crop helpers
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Roi:
    """A rotated square of the image that becomes the landmark model's input.

    A point at normalised crop coordinates q in [0, 1]^2 sits in the image at
    center + size * R(rotation) @ (q - 0.5), with R the 2D rotation matrix in
    image axes (y down), so a positive rotation turns the crop clockwise on
    screen. rotation = 0 means the person stands upright in the image.
    """

    center: np.ndarray  # (2,) pixels
    size: float  # side, pixels
    rotation: float  # radians

    def rotation_matrix(self) -> np.ndarray:
        """(2, 2) R(rotation): crop axes -> image axes."""
        c, s = math.cos(self.rotation), math.sin(self.rotation)
        return np.array([[c, -s], [s, c]])


def roi_from_alignment(
    hip: np.ndarray, scale_point: np.ndarray, *, scale: float = ROI_SCALE
) -> Roi:
    """The landmark model's ROI from the detector's two full-body alignment points.

    The body lies in the circle centred on the hip centre through the scale
    point; the crop is that circle's square, enlarged by `scale`, turned so the
    hip -> scale-point direction points up in the crop.

    Args:
        hip: (2,) hip centre, pixels.
        scale_point: (2,) full-body scale point, pixels.
        scale: enlargement of the circle's square (the model expects 1.25).
    """
    hip = np.asarray(hip, dtype=np.float64)
    up = np.asarray(scale_point, dtype=np.float64) - hip
    radius = float(np.hypot(*up))
    if radius == 0:
        raise ValueError("hip and scale_point coincide: the ROI would be empty")
    # The crop's +x axis, in image axes, is `up` turned 90 degrees clockwise
    # on screen; for an upright person up = (0, -1) and +x = (1, 0).
    rotation = math.atan2(up[0], -up[1])
    return Roi(center=hip, size=2 * radius * scale, rotation=rotation)


# A `person_box` is 2 * PERSON_HALF_LENGTH * r long, the alignment ROI
# 2 * ROI_SCALE * r: this scale turns the first back into the second.
BOX_ROI_SCALE = ROI_SCALE / PERSON_HALF_LENGTH


def roi_from_box(box: np.ndarray, *, scale: float = BOX_ROI_SCALE) -> Roi:
    """An upright ROI for a plain (4,) x0, y0, x1, y1 person box (no keypoints).

    The crop is the square on the box's long side, centred on the box and
    enlarged by `scale`; the default gives an upright person's `person_box`
    the same crop as their alignment keypoints would.
    """
    box = np.asarray(box, dtype=np.float64)
    if box.shape != (4,) or not np.all(box[2:] > box[:2]):
        raise ValueError(f"box must be (4,) x0, y0, x1, y1 with x1 > x0 and y1 > y0, got {box}")
    size = float(np.max(box[2:] - box[:2])) * scale
    return Roi(center=(box[:2] + box[2:]) / 2, size=size, rotation=0.0)


def roi_to_crop_matrix(roi: Roi, crop_size: int) -> np.ndarray:
    """(2, 3) affine matrix taking image pixels to crop pixels of a crop_size square.

    Inverse of `crop_to_image`: q = crop_size * (R^T (p - center) / size + 0.5).
    """
    linear = (crop_size / roi.size) * roi.rotation_matrix().T
    offset = crop_size / 2 - linear @ roi.center
    return np.concatenate([linear, offset[:, None]], axis=1)


def image_to_crop(points: np.ndarray, roi: Roi, crop_size: int) -> np.ndarray:
    """(..., 2) image pixels -> (..., 2) crop pixels."""
    matrix = roi_to_crop_matrix(roi, crop_size)
    return np.asarray(points) @ matrix[:, :2].T + matrix[:, 2]


def crop_to_image(points: np.ndarray, roi: Roi, crop_size: int) -> np.ndarray:
    """(..., 2) crop pixels -> (..., 2) image pixels."""
    normalised = np.asarray(points, dtype=np.float64) / crop_size - 0.5
    return roi.center + roi.size * normalised @ roi.rotation_matrix().T


def warp_crop(image: np.ndarray, roi: Roi, crop_size: int) -> np.ndarray:
    """Cut the rotated square `roi` out of image (H, W, C) as a (crop_size, crop_size, C) array.

    Parts of the ROI outside the image are black (zeros).
    """
    return cv2.warpAffine(
        image,
        roi_to_crop_matrix(roi, crop_size),
        (crop_size, crop_size),
        flags=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )


def decode_landmarks(
    raw_landmarks: np.ndarray,
    raw_world: np.ndarray,
    roi: Roi,
    crop_size: int = LANDMARKER_INPUT_SIZE,
    num_landmarks: int = NUM_BODY_LANDMARKS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Turn the landmark model's raw outputs into image-space landmarks.

    Args:
        raw_landmarks: (J', 5) x, y (crop pixels), z, visibility logit,
            presence logit; J' >= num_landmarks.
        raw_world: (J', 3) world landmarks in metres, in the crop's axes.
        roi: the crop the model saw.
        crop_size: side of the model input, pixels.
        num_landmarks: how many leading landmarks to keep (33 body points;
            the rest are auxiliary points for ROI tracking).

    Returns:
        keypoints (J, 2) image pixels; visibility (J,) and presence (J,) in
        0..1; world (J, 3) metres, turned back so x, y follow the image axes.
    """
    raw_landmarks = np.asarray(raw_landmarks, dtype=np.float64)
    raw_world = np.asarray(raw_world, dtype=np.float64)
    if raw_landmarks.ndim != 2 or raw_landmarks.shape[1] != 5 or len(raw_landmarks) < num_landmarks:
        raise ValueError(
            f"raw_landmarks must have shape (>= {num_landmarks}, 5), got {raw_landmarks.shape}"
        )
    if raw_world.shape != (len(raw_landmarks), 3):
        raise ValueError(
            f"raw_world must have shape ({len(raw_landmarks)}, 3), got {raw_world.shape}"
        )
    body = raw_landmarks[:num_landmarks]
    keypoints = crop_to_image(body[:, :2], roi, crop_size)
    visibility = sigmoid(body[:, 3])
    presence = sigmoid(body[:, 4])
    # The model predicts world points as seen upright in the crop; undo the
    # crop's rotation (about the camera axis) so they share the image's axes.
    world = raw_world[:num_landmarks].copy()
    world[:, :2] = world[:, :2] @ roi.rotation_matrix().T
    return keypoints, visibility, presence, world


# --------------------------------------------------------------------------
# Model wrappers
# --------------------------------------------------------------------------


@contextmanager
def _quiet_stderr() -> Iterator[None]:
    """Silence the C++ runtime's stderr while a model loads: LiteRT announces its CPU delegate
    on every load ("INFO: Created TensorFlow Lite XNNPACK delegate"), ignoring log-level
    variables, which would bury the command line's one-line messages."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _load_interpreter(model_path: Path, num_threads: int, input_size: int) -> Interpreter:
    """Open a TFLite model and check it takes a (1, input_size, input_size, 3) float image."""
    model_path = Path(model_path)
    if not model_path.is_file():
        raise FileNotFoundError(f"model_path: no model file at {model_path}")
    if num_threads < 1:
        raise ValueError(f"num_threads must be >= 1, got {num_threads}")
    try:
        with _quiet_stderr():
            interpreter = Interpreter(model_path=str(model_path), num_threads=num_threads)
            interpreter.allocate_tensors()
    except ValueError as error:
        raise ValueError(
            f"model_path: {model_path} is not a readable TFLite model ({error})"
        ) from error
    (input_detail,) = interpreter.get_input_details()
    want = (1, input_size, input_size, 3)
    if tuple(input_detail["shape"]) != want or input_detail["dtype"] != np.float32:
        raise ValueError(
            f"model_path: {model_path} takes {tuple(input_detail['shape'])} "
            f"{input_detail['dtype'].__name__}, expected {want} float32"
        )
    return interpreter


def _output_index(interpreter: Interpreter, shape: tuple[int, ...], model_path: Path) -> int:
    """Index of the output tensor with this shape (names differ between exports, shapes do not)."""
    matches = [d["index"] for d in interpreter.get_output_details() if tuple(d["shape"]) == shape]
    if len(matches) != 1:
        found = [tuple(d["shape"]) for d in interpreter.get_output_details()]
        raise ValueError(
            f"model_path: {model_path} has no single output of shape {shape}; outputs {found}"
        )
    return matches[0]


class BlazePoseDetector:
    """BlazePose person detector (`pose_detection.tflite`), a `Detector`.

    Not thread-safe: one instance per thread or process.
    """

    def __init__(
        self,
        model_path: Path,
        *,
        score_threshold: float = 0.5,
        nms_iou: float = 0.3,
        num_threads: int = 2,
    ) -> None:
        """
        Args:
            model_path: the pose_detection.tflite file.
            score_threshold: detections scoring below this (0..1) are dropped.
            nms_iou: anchors whose boxes overlap a better one by more than
                this IoU are merged into it (weighted NMS).
            num_threads: CPU threads for inference.
        """
        if not 0 <= score_threshold <= 1:
            raise ValueError(f"score_threshold must be in 0..1, got {score_threshold}")
        if not 0 <= nms_iou <= 1:
            raise ValueError(f"nms_iou must be in 0..1, got {nms_iou}")
        self.model_path = Path(model_path)
        self.score_threshold = score_threshold
        self.nms_iou = nms_iou
        self._interpreter = _load_interpreter(self.model_path, num_threads, DETECTOR_INPUT_SIZE)
        self._input_index = self._interpreter.get_input_details()[0]["index"]
        width = 4 + 2 * DETECTOR_NUM_KEYPOINTS
        self._boxes_index = _output_index(
            self._interpreter, (1, DETECTOR_NUM_ANCHORS, width), self.model_path
        )
        self._scores_index = _output_index(
            self._interpreter, (1, DETECTOR_NUM_ANCHORS, 1), self.model_path
        )
        self.anchors = ssd_anchors()

    def preprocess(self, image_bgr: np.ndarray) -> tuple[np.ndarray, Letterbox]:
        """(H, W, 3) uint8 BGR -> (1, 224, 224, 3) float32 RGB in [-1, 1], and the letterbox."""
        check_image(image_bgr)
        square, transform = letterbox(image_bgr, DETECTOR_INPUT_SIZE)
        rgb = cv2.cvtColor(square, cv2.COLOR_BGR2RGB)
        return (rgb.astype(np.float32) / 127.5 - 1.0)[None], transform

    def infer(self, tensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(1, 224, 224, 3) input -> raw boxes (2254, 12) and score logits (2254,)."""
        self._interpreter.set_tensor(self._input_index, tensor)
        self._interpreter.invoke()
        raw_boxes = self._interpreter.get_tensor(self._boxes_index)[0]
        raw_scores = self._interpreter.get_tensor(self._scores_index)[0, :, 0]
        return raw_boxes, raw_scores

    def postprocess(
        self, raw_boxes: np.ndarray, raw_scores: np.ndarray, transform: Letterbox
    ) -> list[Detection]:
        """Decode, threshold, merge overlapping anchors and map back to image pixels.

        Detection.box is the whole-body `person_box`, clipped to the image;
        Detection.keypoints is (4, 2): hip centre, full-body scale point,
        shoulder centre, upper-body scale point.
        """
        boxes, keypoints, scores = decode_detections(raw_boxes, raw_scores, self.anchors)
        keep = scores >= self.score_threshold
        # NMS on the head boxes: they are fixed-size squares around each
        # anchor's head estimate, so their IoU measures how close two heads are.
        _, scores, keypoints = weighted_nms(
            boxes[keep], scores[keep], keypoints[keep], self.nms_iou
        )
        upper = np.tile(transform.image_size, 2)
        detections = []
        for score, points in zip(scores, keypoints, strict=True):
            points_px = transform.to_image(points * DETECTOR_INPUT_SIZE)
            box = np.clip(person_box(points_px), 0, upper)
            detections.append(Detection(box=box, score=float(score), keypoints=points_px))
        return detections

    def __call__(self, image_bgr: np.ndarray) -> list[Detection]:
        """(H, W, 3) uint8 BGR frame -> detections, best score first."""
        tensor, transform = self.preprocess(image_bgr)
        return self.postprocess(*self.infer(tensor), transform)


class BlazePoseLandmarker:
    """BlazePose 33-landmark model (`pose_landmark_full.tflite`), a `PoseEstimator`.

    Not thread-safe: one instance per thread or process.
    """

    def __init__(self, model_path: Path, *, num_threads: int = 2) -> None:
        """
        Args:
            model_path: the pose_landmark_full.tflite file.
            num_threads: CPU threads for inference.
        """
        self.model_path = Path(model_path)
        self._interpreter = _load_interpreter(self.model_path, num_threads, LANDMARKER_INPUT_SIZE)
        self._input_index = self._interpreter.get_input_details()[0]["index"]
        num = LANDMARKER_NUM_OUTPUT_LANDMARKS
        self._landmarks_index = _output_index(self._interpreter, (1, num * 5), self.model_path)
        self._flag_index = _output_index(self._interpreter, (1, 1), self.model_path)
        self._world_index = _output_index(self._interpreter, (1, num * 3), self.model_path)

    @staticmethod
    def roi_for(box: Detection | Pose | np.ndarray) -> Roi:
        """The crop for a Detection or a previous Pose (turned by their alignment points) or a
        plain box (upright)."""
        if isinstance(box, Pose):
            if box.alignment is not None:
                return roi_from_alignment(box.alignment[0], box.alignment[1])
            return roi_from_box(box.bbox())
        if isinstance(box, Detection):
            if box.keypoints is not None and len(box.keypoints) >= 2:
                return roi_from_alignment(
                    box.keypoints[HIP_CENTER], box.keypoints[FULL_BODY_SCALE_POINT]
                )
            return roi_from_box(box.box)
        return roi_from_box(np.asarray(box))

    def preprocess(self, image_bgr: np.ndarray, roi: Roi) -> np.ndarray:
        """(H, W, 3) uint8 BGR and an ROI -> (1, 256, 256, 3) float32 RGB crop in [0, 1]."""
        check_image(image_bgr)
        crop = warp_crop(image_bgr, roi, LANDMARKER_INPUT_SIZE)
        rgb = cv2.cvtColor(crop, cv2.COLOR_BGR2RGB)
        return (rgb.astype(np.float32) / 255.0)[None]

    def infer(self, tensor: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
        """(1, 256, 256, 3) input -> raw landmarks (39, 5), pose flag, raw world (39, 3)."""
        self._interpreter.set_tensor(self._input_index, tensor)
        self._interpreter.invoke()
        landmarks = self._interpreter.get_tensor(self._landmarks_index).reshape(-1, 5)
        # Unlike visibility and presence, the pose flag leaves the network as a
        # probability already (~3e-5 on a black crop, ~0.999 on a person).
        flag = float(self._interpreter.get_tensor(self._flag_index).reshape(()))
        world = self._interpreter.get_tensor(self._world_index).reshape(-1, 3)
        return landmarks, flag, world

    def postprocess(
        self, raw_landmarks: np.ndarray, flag: float, raw_world: np.ndarray, roi: Roi
    ) -> Pose:
        """Raw outputs -> a Pose with 33 landmarks in image pixels (see `decode_landmarks`)."""
        keypoints, visibility, presence, world = decode_landmarks(raw_landmarks, raw_world, roi)
        aux = np.asarray(raw_landmarks, dtype=np.float64)[[AUX_HIP_CENTER, AUX_SCALE_POINT], :2]
        return Pose(
            keypoints=keypoints,
            confidence=visibility,
            world=world,
            presence=presence,
            score=flag,
            alignment=crop_to_image(aux, roi, LANDMARKER_INPUT_SIZE),
        )

    def estimate(self, image_bgr: np.ndarray, roi: Roi) -> Pose:
        """Pose of the person in `roi` of an (H, W, 3) uint8 BGR frame."""
        return self.postprocess(*self.infer(self.preprocess(image_bgr, roi)), roi)

    def __call__(self, image_bgr: np.ndarray, box: Detection | Pose | np.ndarray) -> Pose:
        """Pose of the person given by a Detection, their previous Pose, or a (4,) box."""
        return self.estimate(image_bgr, self.roi_for(box))
