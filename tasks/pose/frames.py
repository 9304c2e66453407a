"""Reading a range of frames from a video, one at a time, so memory stays at one frame."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from tasks.errors import BadInput


def read_frames(path: Path, start: int, end: int) -> Iterator[tuple[int, np.ndarray]]:
    """Yield ``(index, frame)`` for frames ``[start, end)`` of ``path`` (BGR uint8).

    Seeks to ``start`` and checks where the decoder landed, so a chunk never silently starts on
    the wrong frame. Raises :class:`BadInput` if the file has fewer frames than asked for.
    """
    if not 0 <= start <= end:
        raise ValueError(f"frame range must satisfy 0 <= start <= end, got [{start}, {end})")
    capture = cv2.VideoCapture(str(path))
    try:
        if not capture.isOpened():
            raise BadInput(str(path), "cannot be opened as a video any more (moved or changed?)")
        if start:
            capture.set(cv2.CAP_PROP_POS_FRAMES, start)
            landed = int(capture.get(cv2.CAP_PROP_POS_FRAMES))
            if landed != start:
                # Inexact seek: start over and step forward; slower but always right.
                capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
                for _ in range(start):
                    if not capture.grab():
                        raise BadInput(str(path), f"ends before frame {start}")
        for index in range(start, end):
            ok, frame = capture.read()
            if not ok:
                raise BadInput(str(path), f"frame {index} does not decode (file changed?)")
            yield index, frame
    finally:
        capture.release()
