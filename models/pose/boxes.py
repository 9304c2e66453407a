"""Backend-neutral image and box helpers of the pose models: IoU, non-maximum suppression,
letterboxing, the input image check. Boxes are (x0, y0, x1, y1) image pixels."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


def box_iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Intersection over union of one (4,) box with each of (M, 4) boxes (x0, y0, x1, y1).

    Returns (M,) IoU in 0..1; 0 where the union is empty.
    """
    top_left = np.maximum(box[:2], boxes[:, :2])
    bottom_right = np.minimum(box[2:], boxes[:, 2:])
    inter = np.prod(np.clip(bottom_right - top_left, 0, None), axis=1)
    area = np.prod(np.clip(box[2:] - box[:2], 0, None))
    areas = np.prod(np.clip(boxes[:, 2:] - boxes[:, :2], 0, None), axis=1)
    union = area + areas - inter
    return np.divide(inter, union, out=np.zeros_like(inter, dtype=np.float64), where=union > 0)


def intersections(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(A, B) intersection areas of (A, 4) and (B, 4) boxes."""
    low = np.maximum(a[:, None, :2], b[None, :, :2])
    high = np.minimum(a[:, None, 2:], b[None, :, 2:])
    return np.prod(np.clip(high - low, 0, None), axis=2)


def box_areas(boxes: np.ndarray) -> np.ndarray:
    return np.prod(boxes[:, 2:] - boxes[:, :2], axis=1)


def covered_shares(boxes: np.ndarray) -> np.ndarray:
    """(O, O) share of box i's area that box j covers, 0 on the diagonal."""
    share = intersections(boxes, boxes) / box_areas(boxes)[:, None]
    np.fill_diagonal(share, 0.0)
    return share


def nms(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float) -> np.ndarray:
    """Plain non-maximum suppression.

    Args:
        boxes: (M, 4) x0, y0, x1, y1.
        scores: (M,).
        iou_threshold: a box is dropped when its IoU with a kept, better box
            is above this.

    Returns:
        (M',) int indices of the kept boxes, best score first.
    """
    order = np.argsort(-np.asarray(scores), kind="stable")
    keep = []
    while len(order):
        best, rest = order[0], order[1:]
        keep.append(best)
        order = rest[box_iou(boxes[best], boxes[rest]) <= iou_threshold]
    return np.array(keep, dtype=np.int64)


@dataclass(frozen=True)
class Letterbox:
    """How an image was fitted, aspect kept, into a square model input.

    input = image * scale + pad, per axis (x, y).
    """

    scale: np.ndarray  # (2,) input pixels per image pixel
    pad: np.ndarray  # (2,) input pixels of padding before the image
    image_size: np.ndarray  # (2,) width, height of the original image

    def to_image(self, points: np.ndarray) -> np.ndarray:
        """(..., 2) input pixels -> (..., 2) image pixels."""
        return (points - self.pad) / self.scale


def letterbox(image: np.ndarray, size: int) -> tuple[np.ndarray, Letterbox]:
    """Resize `image` (H, W, C) to fit a size x size square, padding the rest with zeros.

    Returns the (size, size, C) square (a new array) and the transform back.
    """
    height, width = image.shape[:2]
    factor = size / max(height, width)
    new_w, new_h = max(1, round(width * factor)), max(1, round(height * factor))
    # Bilinear, not INTER_AREA: on the multi-person sample, area averaging
    # (smoother) lowered the weaker person's detection score so much that it was
    # found in 25 of 100 frames instead of 35; it also costs 7 ms instead of 0.1.
    # MediaPipe's own graphs sample bilinearly too, so this is what the model saw.
    resized = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_LINEAR)
    pad_x, pad_y = (size - new_w) // 2, (size - new_h) // 2
    square = cv2.copyMakeBorder(
        resized,
        pad_y,
        size - new_h - pad_y,
        pad_x,
        size - new_w - pad_x,
        cv2.BORDER_CONSTANT,
        value=0,
    )
    transform = Letterbox(
        scale=np.array([new_w / width, new_h / height]),
        pad=np.array([pad_x, pad_y], dtype=np.float64),
        image_size=np.array([width, height], dtype=np.float64),
    )
    return square, transform


def check_image(image_bgr: np.ndarray) -> None:
    if not isinstance(image_bgr, np.ndarray) or image_bgr.ndim != 3 or image_bgr.shape[2] != 3:
        shape = getattr(image_bgr, "shape", type(image_bgr).__name__)
        raise ValueError(f"image_bgr must be an (H, W, 3) BGR array, got {shape}")
    if image_bgr.dtype != np.uint8:
        raise ValueError(f"image_bgr must be uint8, got {image_bgr.dtype}")
    if image_bgr.shape[0] == 0 or image_bgr.shape[1] == 0:
        raise ValueError(f"image_bgr is empty: shape {image_bgr.shape}")
