"""Reading a range of frames from a video, one at a time, so memory stays at one frame."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np

from tasks.errors import BadInput


def read_frames(
    path: Path, start: int, end: int, source: Sequence[int] | None = None
) -> Iterator[tuple[int, np.ndarray]]:
    """Yield ``(index, frame)`` for frames ``[start, end)`` of ``path`` (BGR uint8).

    ``source`` re-times a variable-rate video: the decoded frame shown at each of frames
    ``[start, end)`` of its constant-rate grid (non-decreasing; ingest's ``source_frames``).
    Seeks to the first frame and checks where the decoder landed, so a chunk never silently
    starts on the wrong frame. Raises :class:`BadInput` if the file has fewer frames than asked.
    """
    if not 0 <= start <= end:
        raise ValueError(f"frame range must satisfy 0 <= start <= end, got [{start}, {end})")
    if source is None:
        yield from _decoded(path, start, end)
        return
    if len(source) != end - start:
        raise ValueError(f"source gives {len(source)} frames for [{start}, {end})")
    if start == end:
        return
    decoded = _decoded(path, source[0], source[-1] + 1)
    at, frame = next(decoded)
    for index, wanted in enumerate(source, start):
        while at < wanted:
            at, frame = next(decoded)
        yield index, frame


def _decoded(path: Path, start: int, end: int) -> Iterator[tuple[int, np.ndarray]]:
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
