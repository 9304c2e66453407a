"""Ingest speed: the whole ingest scan (decode + histograms + cut detection + stills) against a
bare OpenCV decode of the same file, in the same run.

Input: the bundled two-person sample (1088x1920 H.264, 100 frames) looped 10 times into one
1000-frame file (the seams join one camera to itself, so they are not cuts). Prints frames per
second of both and, last, their ratio (1.0 would mean the scan costs nothing beyond decoding).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import cv2

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._common import looped_sample  # noqa: E402
from tasks.ingest.config import IngestConfig  # noqa: E402
from tasks.ingest.probe import scan_video  # noqa: E402

LOOPS = 10


def bare_decode(path: Path) -> int:
    capture = cv2.VideoCapture(str(path))
    frames = 0
    while capture.read()[0]:
        frames += 1
    capture.release()
    return frames


def best_of(runs: int, work) -> tuple[float, object]:
    best, result = float("inf"), None
    for _ in range(runs):
        start = time.perf_counter()
        result = work()
        best = min(best, time.perf_counter() - start)
    return best, result


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        video = looped_sample(Path(tmp), LOOPS)
        decode_s, frames = best_of(3, lambda: bare_decode(video))
        scan_s, scan = best_of(3, lambda: scan_video(video, IngestConfig()))
    assert scan.probe.frames == frames, (scan.probe.frames, frames)
    print(f"input: {frames} frames {scan.probe.width}x{scan.probe.height} {scan.probe.codec}")
    print(f"shots found: {len(scan.shots)}")
    print(f"bare_decode_fps: {frames / decode_s:.1f} fps")
    print(f"ingest_fps: {frames / scan_s:.1f} fps")
    print(f"ingest_vs_decode: {decode_s / scan_s:.2f} x")


if __name__ == "__main__":
    main()
