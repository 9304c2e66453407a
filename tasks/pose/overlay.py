"""The review overlay: skeletons and track ids drawn on the frames (written as H.264 MP4 by
`tasks.media.H264Writer`, and as PNG stills)."""

from __future__ import annotations

from collections.abc import Iterable

import cv2
import numpy as np

from models.pose.types import BLAZEPOSE_33

# Bones drawn between BlazePose landmarks (by name, so the list reads as anatomy).
BONES = (
    ("left_shoulder", "right_shoulder"),
    ("left_hip", "right_hip"),
    ("left_shoulder", "left_hip"),
    ("right_shoulder", "right_hip"),
    ("left_shoulder", "left_elbow"),
    ("left_elbow", "left_wrist"),
    ("right_shoulder", "right_elbow"),
    ("right_elbow", "right_wrist"),
    ("left_hip", "left_knee"),
    ("left_knee", "left_ankle"),
    ("right_hip", "right_knee"),
    ("right_knee", "right_ankle"),
    ("left_ankle", "left_foot_index"),
    ("right_ankle", "right_foot_index"),
    ("nose", "left_eye"),
    ("nose", "right_eye"),
)
BONE_INDEX = np.array([(BLAZEPOSE_33.index(a), BLAZEPOSE_33.index(b)) for a, b in BONES])
ROLE_COLOURS = {"adversary": (40, 40, 230), "opponent": (230, 160, 40), "other": (160, 160, 160)}


def overlay_size(width: int, height: int, max_side: int) -> tuple[int, int]:
    """Output size: the frame shrunk so its long side is at most ``max_side``, both sides even
    (H.264 with 4:2:0 chroma needs even sides)."""
    scale = min(1.0, max_side / max(width, height))
    return max(2, round(width * scale / 2) * 2), max(2, round(height * scale / 2) * 2)


def draw_people(
    frame: np.ndarray,
    people: Iterable[tuple[int, str, np.ndarray, np.ndarray, np.ndarray]],
    *,
    min_confidence: float = 0.3,
) -> np.ndarray:
    """A copy of ``frame`` with each person drawn: (track id, role, box (4,), keypoints (J, 2),
    confidence (J,)). Joints below ``min_confidence`` and bones touching them are left out."""
    out = frame.copy()
    thickness = max(2, round(max(frame.shape[:2]) / 400))
    for track, role, box, keypoints, confidence in people:
        colour = ROLE_COLOURS.get(role, ROLE_COLOURS["other"])
        x0, y0, x1, y1 = (int(v) for v in np.nan_to_num(box))
        cv2.rectangle(out, (x0, y0), (x1, y1), colour, thickness)
        label = f"#{track} {role}"
        cv2.putText(
            out,
            label,
            (x0, max(0, y0 - 2 * thickness)),
            cv2.FONT_HERSHEY_SIMPLEX,
            thickness / 2.5,
            colour,
            thickness,
            cv2.LINE_AA,
        )
        good = np.isfinite(keypoints).all(axis=1) & (confidence >= min_confidence)
        for a, b in BONE_INDEX:
            if good[a] and good[b]:
                pa, pb = keypoints[a].astype(int), keypoints[b].astype(int)
                cv2.line(out, tuple(pa), tuple(pb), colour, thickness, cv2.LINE_AA)
        for point in keypoints[good].astype(int):
            cv2.circle(out, tuple(point), thickness + 1, (255, 255, 255), -1, cv2.LINE_AA)
    return out
