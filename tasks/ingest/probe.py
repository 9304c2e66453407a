"""Probing a video file: identity, what OpenCV can decode, shot cuts and the chunk plan."""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from storage.files import sha256_file
from tasks.errors import BadInput
from tasks.ingest.config import IngestConfig

HUE_BINS, SAT_BINS = 30, 32


@dataclass(frozen=True)
class VideoFile:
    """A video file on disk and its identity, the SHA-256 of its bytes."""

    path: str
    video_id: str
    size_bytes: int


@dataclass(frozen=True)
class Probe:
    """What decoding the whole file found. ``fps`` and ``frames`` describe the constant-rate
    timeline every later stage uses; for a variable-rate video, ``source_frames[i]`` is the
    decoded frame shown at grid frame ``i`` (``None``: the grid is the decoded frames)."""

    fps: float
    frames: int
    frames_declared: int
    width: int
    height: int
    codec: str
    duration_s: float
    frames_decoded: int
    source_frames: np.ndarray | None = None
    fps_range: tuple[float, float] | None = None  # slowest, fastest rate of a variable video


@dataclass(frozen=True)
class Shot:
    """Frames ``[start, end)`` between two cuts; ``cut_distance`` is the histogram distance at the
    cut that opened it (``None`` for the first shot); ``thumbnail`` is a PNG of its first frame."""

    index: int
    start: int
    end: int
    cut_distance: float | None
    thumbnail: bytes


@dataclass(frozen=True)
class Chunk:
    index: int
    shot: int
    start: int
    end: int


@dataclass(frozen=True)
class Scan:
    probe: Probe
    distances: np.ndarray
    shots: list[Shot]


def check_file(path: Path) -> None:
    """Raise :class:`BadInput` unless ``path`` is a non-empty readable regular file."""
    if not path.exists():
        raise BadInput(str(path), "no such file")
    if path.is_dir():
        raise BadInput(str(path), "is a directory, not a video file")
    if not path.is_file():
        raise BadInput(str(path), "is not a regular file")
    if path.stat().st_size == 0:
        raise BadInput(str(path), "is empty (0 bytes)")
    if not os.access(path, os.R_OK):
        raise BadInput(str(path), "is not readable (permission denied)")


def check_duration(path: Path, min_s: float, needed_by: str) -> None:
    """Raise :class:`BadInput` when the container says ``path`` lasts less than ``min_s`` seconds
    (``needed_by`` names the setting that asks for them). Read from the header, not decoded: a
    file whose header gives no frame count or rate is left to ingest, which decodes it all."""
    check_file(path)
    capture = cv2.VideoCapture(str(path))
    try:
        frames = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        fps = float(capture.get(cv2.CAP_PROP_FPS))
    finally:
        capture.release()
    if frames > 0 and math.isfinite(fps) and fps > 0 and frames / fps < min_s:
        raise BadInput(
            str(path),
            f"lasts {frames / fps:.2f} s ({frames} frame{'s' if frames != 1 else ''} at "
            f"{fps:g} fps), shorter than the "
            f"{min_s:g} s {needed_by} needs: give a longer video, or stop before that stage "
            "with --until",
        )


def identify(path: Path) -> VideoFile:
    """The checked file and its SHA-256 identity."""
    check_file(path)
    resolved = path.resolve()
    return VideoFile(
        str(resolved),
        sha256_file(resolved, progress=f"hash {path.name}"),
        resolved.stat().st_size,
    )


def hs_histogram(frame_bgr: np.ndarray, width: int) -> np.ndarray:
    """Hue-saturation histogram (HUE_BINS, SAT_BINS) of a frame shrunk to ``width``, summing to 1.

    Brightness is left out so a fighter stepping into a shadow is not a cut.
    """
    h, w = frame_bgr.shape[:2]
    if w > width:
        # Bilinear, as it always was (INTER_AREA was passed where OpenCV takes `dst`, so it never
        # acted): the thresholds were set on it, and it takes 0.3 ms a frame against 5.6 ms.
        size = (width, max(1, round(h * width / w)))
        frame_bgr = cv2.resize(frame_bgr, size, interpolation=cv2.INTER_LINEAR)
    hsv = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2HSV)
    hist = cv2.calcHist([hsv], [0, 1], None, [HUE_BINS, SAT_BINS], [0, 180, 0, 256])
    return hist / max(float(hist.sum()), 1.0)


def histogram_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Bhattacharyya distance between two normalised histograms: 0 identical, 1 disjoint."""
    return float(cv2.compareHist(a, b, cv2.HISTCMP_BHATTACHARYYA))


# Width (pixels) of the grey thumbnails whose correlation is the structure distance: small
# enough that noise and small motions blur away, large enough to hold the picture's layout.
STRUCTURE_WIDTH = 64


def grey_thumbnail(
    frame_bgr: np.ndarray, width: int = STRUCTURE_WIDTH
) -> tuple[np.ndarray, float, float]:
    """The frame in grey, ``width`` pixels wide, slightly blurred, with zero mean and unit
    variance (a flat frame stays all zeros), and its brightness and contrast before that: the
    mean and standard deviation in grey levels (0-255)."""
    h, w = frame_bgr.shape[:2]
    grey = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2GRAY).astype(np.float32)
    small = cv2.resize(grey, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (3, 3), 0)
    brightness = float(small.mean())
    small -= brightness
    spread = float(small.std())
    # Below a thousandth of a grey level the spread is float32 rounding of the mean, not a
    # picture: scaled up, it correlated at random with the next flat frame.
    return (small / spread if spread > 1e-3 else np.zeros_like(small)), brightness, spread


def structure_distance(a: np.ndarray, b: np.ndarray) -> float:
    """(1 - correlation) / 2 of two `grey_thumbnail`s: 0 the same picture, 0.5 unrelated, 1 its
    negative. Colour histograms miss a cut to a mirrored or re-framed view; this does not."""
    return float((1.0 - (a * b).mean()) / 2.0)


# Ours rather than PySceneDetect's detectors (benchmarks/cut_detectors.py, 32 inputs made from
# the sample's views): its ContentDetector and AdaptiveDetector at their defaults pass the tests'
# cases but drop a cut 13 frames after another, and AdaptiveDetector misses a cut made while
# the camera pans; tuned, AdaptiveDetector gets more inputs right (it also finds a jump in time
# and a brightness step, which ours misses) but cuts mild hand-held shake (+-1.5 % of the
# width) where ours does not, and on fight footage a false cut costs as much as a missed one:
# it splits the tracks and the world frame. Its HashDetector and HistogramDetector fail the
# tests' cases (a flat synthetic shot; a mirrored view). All four cut a fade to black and back
# where it turns black (tuned, AdaptiveDetector also a slow fade to 5 % and back, and
# ContentDetector puts a fade into another view's cut a frame before the black); ours, which
# leaves blank frames out, does not. PySceneDetect is about twice as fast (one pass over the
# 100-frame sample: 0.7-1.0 s against 1.8-2.2 s for ours on 2 busy shared cores, 0.5-0.6 s
# against 1.0 s on an idle machine; much of ours is its full-frame grey thumbnail), which
# matters little: the whole ingest costs a tenth of pose and lift together per minute of
# footage (docs/scaling.md).
class CutDetector:
    """Declares a cut at frame ``i`` when the histogram distance to the frame it is compared with
    (the one before, or the last one before it that was not blank) exceeds ``threshold`` or the
    structure distance exceeds ``structure_threshold``, and the previous cut is at least
    ``min_shot_frames`` back."""

    def __init__(self, threshold: float, min_shot_frames: int, structure_threshold: float = 1.0):
        self.threshold = threshold
        self.structure_threshold = structure_threshold
        self.min_shot_frames = min_shot_frames
        self.last_cut = 0

    def update(self, frame: int, distance: float, structure: float = 0.0) -> bool:
        changed = distance > self.threshold or structure > self.structure_threshold
        if changed and frame - self.last_cut >= self.min_shot_frames:
            self.last_cut = frame
            return True
        return False


def find_cuts(distances: np.ndarray, threshold: float, min_shot_frames: int) -> list[int]:
    """Frames that open a new shot, given ``distances[i]`` between frames ``i - 1`` and ``i``."""
    detector = CutDetector(threshold, min_shot_frames)
    return [i for i in range(1, len(distances)) if detector.update(i, float(distances[i]))]


def retime(
    times_s: np.ndarray, spread: float
) -> tuple[float, np.ndarray, tuple[float, float]] | None:
    """For decoded frames shown at ``times_s``: ``None`` when their intervals are even (within
    ``spread`` of the median, 5th to 95th percentile), else the grid rate (the fastest
    interval's), per grid frame the decoded frame on screen at that moment, and the slowest and
    fastest rates the intervals give."""
    times_s = np.asarray(times_s, dtype=np.float64)
    intervals = np.diff(times_s)
    # Timestamps that do not increase (a container without them) say nothing: keep the frames.
    if len(intervals) < 2 or not np.all(np.isfinite(intervals)) or np.any(intervals <= 0):
        return None
    low, median, high = np.percentile(intervals, [5, 50, 95])
    if (high - low) / median <= spread:
        return None
    rate = round(1.0 / low, 3)  # the timestamps' rounding aside, a rate like 60 reads 60
    grid = (
        times_s[0] + np.arange(int(np.floor((times_s[-1] - times_s[0]) * rate + 1e-6)) + 1) / rate
    )
    # The frame on screen at t is the last one shown at or before it (a tolerance of a
    # thousandth of an interval absorbs the timestamps' millisecond rounding).
    shown = np.searchsorted(times_s, grid + 1e-3 * low, side="right") - 1
    return rate, shown.clip(0, len(times_s) - 1), (1.0 / intervals.max(), 1.0 / intervals.min())


def plan_chunks(shots: list[Shot], chunk_frames: int) -> list[Chunk]:
    """Split every shot into chunks of at most ``chunk_frames`` frames, in frame order."""
    chunks: list[Chunk] = []
    for shot in shots:
        for start in range(shot.start, shot.end, chunk_frames):
            chunks.append(
                Chunk(len(chunks), shot.index, start, min(start + chunk_frames, shot.end))
            )
    return chunks


def unopenable_reason(path: Path) -> str:
    """Why a file OpenCV cannot open is unusable, told apart by its first bytes."""
    with path.open("rb") as f:
        head = f.read(12)
    if head[4:8] == b"ftyp":
        return (
            "is an MP4/MOV file that cannot be opened: it is probably truncated or damaged "
            "(its index is missing)"
        )
    return "is not a video file OpenCV can read"


def fourcc_text(code: float) -> str:
    value = int(code)
    text = "".join(chr((value >> (8 * i)) & 0xFF) for i in range(4))
    return text.strip("\0 ").lower() if text.isprintable() and value else "unknown"


def _frames(capture: cv2.VideoCapture) -> Iterator[np.ndarray]:
    while True:
        ok, frame = capture.read()
        if not ok:
            return
        yield frame


def _thumbnail(frame: np.ndarray, width: int) -> bytes:
    h, w = frame.shape[:2]
    small = cv2.resize(frame, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)
    ok, png = cv2.imencode(".png", small)
    if not ok:
        raise RuntimeError("OpenCV could not encode a PNG thumbnail")
    return png.tobytes()


def scan_video(path: Path, config: IngestConfig) -> Scan:
    """Decode every frame of ``path`` once: count them, find shot cuts, keep one still per shot.

    Memory stays bounded by one frame and one histogram, whatever the length of the video.
    Raises :class:`BadInput` naming the file when it is not a complete, decodable video.
    """
    capture = cv2.VideoCapture(str(path))
    try:
        if not capture.isOpened():
            raise BadInput(str(path), unopenable_reason(path))
        fps = float(capture.get(cv2.CAP_PROP_FPS))
        declared = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        codec = fourcc_text(capture.get(cv2.CAP_PROP_FOURCC))
        detector = CutDetector(
            config.cut_threshold, config.min_shot_frames, config.structure_threshold
        )
        distances: list[float] = []
        times_ms: list[float] = []
        cuts: list[tuple[int, float, bytes]] = []
        previous = previous_grey = None
        size = (0, 0)
        frames = tqdm(
            _frames(capture),
            total=max(declared, 0) or None,
            unit="frame",
            desc=f"ingest {path.name}",
            disable=None,
        )
        for index, frame in enumerate(frames):
            hist = hs_histogram(frame, config.histogram_width)
            grey, brightness, contrast = grey_thumbnail(frame)
            # A flat frame has no layout to compare, only colours; a flat, dark one (the middle
            # of a fade to black) not even those (a dark pixel's hue is noise): it is blank, and
            # the next frame that is not is compared with the last that was not, so a fade to
            # black and back is no cut and a fade from one shot into another is one.
            flat = contrast < config.flat_contrast
            blank = flat and brightness < config.dark_level
            distance = 0.0 if previous is None else histogram_distance(previous, hist)
            structure = (
                0.0 if previous_grey is None or flat else structure_distance(previous_grey, grey)
            )
            distances.append(distance)
            times_ms.append(capture.get(cv2.CAP_PROP_POS_MSEC))
            if index == 0:
                size = (frame.shape[1], frame.shape[0])
                cuts.append((0, math.nan, _thumbnail(frame, config.thumbnail_width)))
            elif not blank and previous is not None and detector.update(index, distance, structure):
                cuts.append((index, distance, _thumbnail(frame, config.thumbnail_width)))
            if not blank:
                previous, previous_grey = hist, None if flat else grey
    finally:
        capture.release()

    decoded = len(distances)
    if decoded == 0:
        raise BadInput(str(path), "has no decodable video frames")
    if declared > 0 and decoded < declared * (1.0 - config.truncation_tolerance) - 1:
        raise BadInput(
            str(path),
            f"is truncated or damaged: the container declares {declared} frames "
            f"but only {decoded} decode",
        )
    if not math.isfinite(fps) or fps <= 0:
        raise BadInput(str(path), f"declares no usable frame rate (fps={fps})")
    if decoded < config.min_frames:
        raise BadInput(
            str(path),
            f"has {decoded} frame{'s' if decoded != 1 else ''}; at least {config.min_frames} "
            "are needed (ingest.min_frames)",
        )

    frames, source, fps_range = decoded, None, None
    retimed = retime(np.asarray(times_ms) / 1000.0, config.frame_interval_spread)
    if retimed is not None:
        fps, source, fps_range = retimed
        frames = len(source)
        # A cut opens the shot at the first grid frame showing the frame after it.
        cuts = [(int(np.searchsorted(source, start)), d, png) for start, d, png in cuts]
    ends = [start for start, _, _ in cuts[1:]] + [frames]
    shots = [
        Shot(i, start, end, None if i == 0 else distance, png)
        for i, ((start, distance, png), end) in enumerate(zip(cuts, ends, strict=True))
    ]
    probe = Probe(
        fps=fps,
        frames=frames,
        frames_declared=declared,
        width=size[0],
        height=size[1],
        codec=codec,
        duration_s=frames / fps,
        frames_decoded=decoded,
        source_frames=source,
        fps_range=fps_range,
    )
    return Scan(probe, np.asarray(distances, dtype=np.float64), shots)
