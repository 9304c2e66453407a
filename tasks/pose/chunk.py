"""One chunk of frames through detection, tracking and pose estimation.

Per frame: everyone followed from the previous frame is estimated again in the crop their last
pose points to (the landmark model re-finds a person the detector misses); every
``detect_every`` frames, and whenever nobody is followed, the detector searches the frame and
each person it finds that nobody followed covers is estimated too. Every pose the model accepts
becomes an observation for the tracker, which gives identities (motion + clothing colour).
"""

from __future__ import annotations

import io
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from models.pose.boxes import box_iou
from models.pose.types import Detector, Pose, PoseEstimator
from tasks.pose.config import PoseConfig
from tasks.pose.tracking import DESCRIPTOR_SIZE, Observation, Tracker, appearance


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
    det_frame, det_box, det_score = [], [], []
    joints = 0
    for index, frame in frames:
        if STOP.is_set():
            raise Stopped(f"chunk of frames {start}-{end} stopped at frame {index}")
        height, width = frame.shape[:2]
        poses = [
            p
            for p in (estimator(frame, prev) for prev in following)
            if p.score >= config.pose_score
        ]
        if not following or (index - start) % config.detect_every == 0:
            seen = np.array([p.bbox() for p in poses]).reshape(-1, 4)
            for det in detector(frame):
                if det.score < config.detection_score:
                    continue
                det_frame.append(index)
                det_box.append(det.box)
                det_score.append(det.score)
                if len(seen) and box_iou(det.box, seen).max() > config.redetect_iou:
                    continue
                pose = estimator(frame, det)
                if pose.score >= config.pose_score:
                    poses.append(pose)
        observations, kept = [], []
        for pose in poses:
            box = _clip(pose.bbox(), width, height)
            if box is None:
                continue
            joints = len(pose.keypoints)
            observations.append(Observation(box, pose.score, appearance(frame, box)))
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
    detections = (det_frame, det_box, det_score)
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
