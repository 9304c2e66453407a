"""One chunk of frames through detection, tracking and pose estimation.

Per frame: everyone followed from the previous frame is estimated again in the crop their last
pose points to (the landmark model re-finds a person the detector misses). On every frame whose
index is a multiple of ``detect_every``, and whenever nobody is followed, the detector searches
the frame, and everyone it finds is estimated in the crop of their detection, the people already
followed included. Every pose the model accepts becomes an observation for the tracker, which
gives identities (motion + clothing colour).

Why followed people start again from their detection: a crop that follows the last pose carries
the whole history of crops before it, and the landmark model answers a crop shifted by a few
pixels with keypoints a few pixels off, which never die out (on the sample, two runs that
started 10 frames apart still differed by a median 5 px per joint 90 frames later). Started
again at frames fixed by their index, a person's crops depend on at most the ``detect_every``
frames before, so a chunk that re-reads ``overlap_frames >= detect_every`` frames before its
start finds the keypoints one long chunk finds (tests/test_pose_chunks.py).
"""

from __future__ import annotations

import io
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from models.pose.boxes import box_iou
from models.pose.types import Detection, Detector, Pose, PoseEstimator
from tasks.pose.config import PoseConfig
from tasks.pose.people_tracking import DESCRIPTOR_SIZE, Observation, Tracker, appearance, one_body


@dataclass(frozen=True, eq=False)
class ChunkTracks:
    """What one chunk found. Shape letters: D detections, N observations, J joints.

    Frames are video frame indices; ``obs_track`` are this chunk's own track ids (the merge
    turns them into the video's).
    """

    start: int
    end: int
    seconds: float  # time the chunk took to compute
    det_frame: np.ndarray  # (D,) int
    det_box: np.ndarray  # (D, 4) x0, y0, x1, y1
    det_score: np.ndarray  # (D,)
    obs_frame: np.ndarray  # (N,) int
    obs_track: np.ndarray  # (N,) int
    obs_box: np.ndarray  # (N, 4)
    obs_score: np.ndarray  # (N,) the pose model's person-present score
    keypoints: np.ndarray  # (N, J, 2) pixels
    confidence: np.ndarray  # (N, J)
    world: np.ndarray  # (N, J, 3) metres, NaN when the backend gives none
    colour: np.ndarray  # (N, DESCRIPTOR_SIZE)

    def to_bytes(self) -> bytes:
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **{k: np.asarray(v) for k, v in vars(self).items()})
        return buffer.getvalue()

    @classmethod
    def from_bytes(cls, data: bytes) -> ChunkTracks:
        with np.load(io.BytesIO(data)) as archive:
            values = {name: archive[name] for name in archive.files}
        return cls(**{k: (v.item() if v.ndim == 0 else v) for k, v in values.items()})


# Chunks run in worker threads, which a stop signal never reaches, and Prefect waits for the
# running ones before a stopped command may exit (7 s on a loaded 2-core machine). The flow
# waiting on them sets this as it stops (`tasks.pose.task.track_chunks`), and each chunk ends
# at its next frame.
STOP = threading.Event()


class Stopped(Exception):
    """A chunk left unfinished because its flow is stopping."""


def _clip(box: np.ndarray, width: int, height: int) -> np.ndarray | None:
    clipped = np.clip(box, 0, [width, height, width, height]).astype(np.float64)
    return clipped if clipped[2] - clipped[0] >= 2 and clipped[3] - clipped[1] >= 2 else None


def _search(
    frame: np.ndarray,
    following: list[Pose],
    detector: Detector,
    estimator: PoseEstimator,
    config: PoseConfig,
) -> tuple[list[Pose], list[Detection]]:
    """The poses of one frame the detector searches: each person it finds is estimated afresh
    in the crop of its detection, whether followed or not (an anchor: from here on, a followed
    person's crops no longer depend on the frames before, so a chunk that starts a few frames
    earlier sees the same poses as one long chunk); someone followed whom it misses is
    followed on from their last pose. Returns the poses and the frame's detections."""
    detections = [d for d in detector(frame) if d.score >= config.detection_score]
    boxes = np.array([d.box for d in detections]).reshape(-1, 4)
    matched: dict[int, int] = {}  # detection -> followed person
    if following and len(boxes):
        overlap = np.array([box_iou(p.bbox(), boxes) for p in following])
        rows, cols = linear_sum_assignment(-overlap)
        matched = {
            int(c): int(r)
            for r, c in zip(rows, cols, strict=True)
            if overlap[r, c] > config.redetect_iou
        }
    poses = {}
    for d, k in matched.items():
        pose = estimator(frame, detections[d])
        # An anchor on someone else, on part of them or on nobody leaves them followed.
        if pose.score < config.pose_score or not _same_body(pose, following[k], config):
            pose = estimator(frame, following[k])
        poses[k] = pose
    kept = [poses[k] if k in poses else estimator(frame, p) for k, p in enumerate(following)]
    seen = np.array([p.bbox() for p in kept]).reshape(-1, 4)
    for d, det in enumerate(detections):
        if d in matched:
            continue
        if not len(seen) or box_iou(det.box, seen).max() <= config.redetect_iou:
            kept.append(estimator(frame, det))
            continue
        # A detection overlapping someone followed may be a second person they half hide (a
        # clinch, a crossing): estimated, it is kept if it is a body of its own.
        pose = estimator(frame, det)
        if pose.score >= config.pose_score and not any(
            one_body(pose.bbox(), pose.keypoints, p.bbox(), p.keypoints, config.tracker)
            or _same_body(pose, p, config)
            for p in kept
        ):
            kept.append(pose)
    return kept, detections


def _same_body(pose: Pose, previous: Pose, config: PoseConfig) -> bool:
    """Whether ``pose`` is the body ``previous`` showed a frame before: their keypoints apart
    by a median of less than `anchor_distance` of its height in the image."""
    height = np.ptp(previous.keypoints[:, 1])
    apart = np.median(np.linalg.norm(pose.keypoints - previous.keypoints, axis=-1))
    return bool(height > 0 and apart < config.anchor_distance * height)


def track_chunk(
    frames: Iterable[tuple[int, np.ndarray]],
    *,
    start: int,
    end: int,
    fps: float,
    detector: Detector,
    estimator: PoseEstimator,
    config: PoseConfig,
) -> ChunkTracks:
    """Run frames ``[start, end)`` (given as ``(index, BGR frame)``) through the pose stage's
    per-frame work; see the module docstring."""
    began = time.perf_counter()
    tracker = Tracker(config.tracker, fps, start_frame=start)
    following: list[Pose] = []
    candidates: dict[int, list[tuple[np.ndarray, Pose, np.ndarray]]] = {}
    found: list[tuple[int, Detection]] = []
    joints = 0
    for index, frame in frames:
        if STOP.is_set():
            raise Stopped(f"chunk of frames {start}-{end} stopped at frame {index}")
        height, width = frame.shape[:2]
        if following and index % config.detect_every:
            poses = [estimator(frame, prev) for prev in following]
        else:
            poses, detections = _search(frame, following, detector, estimator, config)
            found += [(index, d) for d in detections]
        poses = [p for p in poses if p.score >= config.pose_score]
        observations, kept = [], []
        for pose in poses:
            box = _clip(pose.bbox(), width, height)
            if box is None:
                continue
            joints = len(pose.keypoints)
            observations.append(
                Observation(box, pose.score, appearance(frame, box), pose.keypoints)
            )
            kept.append(pose)
        ids = tracker.update(observations)
        candidates[index] = [(o.box, p, o.colour) for o, p in zip(observations, kept, strict=True)]
        # Follow everyone the tracker took, and anyone not yet confirmed who is not a duplicate
        # of them (so a new track can be confirmed); never one person twice.
        taken = [o.box for o, i in zip(observations, ids, strict=True) if i is not None]
        following = [p for p, i in zip(kept, ids, strict=True) if i is not None]
        for pose, obs, i in zip(kept, observations, ids, strict=True):
            if i is None and not (
                taken and box_iou(obs.box, np.array(taken)).max() > config.tracker.duplicate_iou
            ):
                following.append(pose)
                taken.append(obs.box)
    detections = ([i for i, _ in found], [d.box for _, d in found], [d.score for _, d in found])
    return _collect(tracker, candidates, start, end, joints, detections, began)


def _collect(tracker, candidates, start, end, joints, detections, began) -> ChunkTracks:
    det_frame, det_box, det_score = detections
    rows = []
    for track in tracker.tracks():
        for offset in np.flatnonzero(track.observed):
            frame = track.first_frame + int(offset)
            box = track.boxes[offset]
            for cand_box, pose, colour in candidates.get(frame, []):
                if np.array_equal(cand_box, box):
                    rows.append((frame, track.track_id, box, track.scores[offset], pose, colour))
                    break
    rows.sort(key=lambda r: (r[0], r[1]))
    n = len(rows)
    world = np.full((n, joints, 3), np.nan, np.float32)
    for i, row in enumerate(rows):
        if row[4].world is not None:
            world[i] = row[4].world
    return ChunkTracks(
        start=start,
        end=end,
        seconds=time.perf_counter() - began,
        det_frame=np.array(det_frame, np.int64),
        det_box=np.array(det_box, np.float64).reshape(-1, 4),
        det_score=np.array(det_score, np.float64),
        obs_frame=np.array([r[0] for r in rows], np.int64),
        obs_track=np.array([r[1] for r in rows], np.int64),
        obs_box=np.array([r[2] for r in rows], np.float64).reshape(-1, 4),
        obs_score=np.array([r[3] for r in rows], np.float64),
        keypoints=np.array([r[4].keypoints for r in rows], np.float32).reshape(n, joints, 2),
        confidence=np.array([r[4].confidence for r in rows], np.float32).reshape(n, joints),
        world=world,
        colour=np.array([r[5] for r in rows], np.float32).reshape(n, DESCRIPTOR_SIZE),
    )
