"""Joining the chunks of a video into one set of tracks with the video's own track ids.

Chunks are tracked independently (so they can run at the same time). A chunk that continues a
shot re-reads a few frames before its start; its tracks are joined to the previous chunk's by
how well their boxes overlap in those shared frames. Tracks never join across a shot cut.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.pose.boxes import box_iou
from tasks.pose.chunk import ChunkTracks
from tasks.pose.people_tracking import TrackSummary, box_to_cxcywh, hungarian

# Two tracks are one person if their boxes overlap this much, on average, in the shared frames.
JOIN_IOU = 0.5


@dataclass(frozen=True)
class ChunkSpan:
    """Where a chunk sits: frames ``[start, end)`` are its own, ``[read_start, start)`` are
    re-read to join it to the previous chunk of the same shot. ``source``: for a variable-rate
    video, the decoded frame shown at each of frames ``[read_start, end)``."""

    index: int
    shot: int
    start: int
    end: int
    read_start: int
    source: tuple[int, ...] | None = None


@dataclass(frozen=True, eq=False)
class VideoTracks:
    """Every chunk's own frames, with the video's track ids; arrays as in :class:`ChunkTracks`.

    ``track_shot`` (T,) gives the shot of track t (ids are 0..T-1).
    """

    det_frame: np.ndarray
    det_box: np.ndarray
    det_score: np.ndarray
    obs_frame: np.ndarray
    obs_track: np.ndarray
    obs_box: np.ndarray
    obs_score: np.ndarray
    keypoints: np.ndarray
    confidence: np.ndarray
    world: np.ndarray
    colour: np.ndarray
    track_shot: np.ndarray


def _rows(chunk: ChunkTracks, keep: np.ndarray) -> dict[str, np.ndarray]:
    names = (
        "obs_frame",
        "obs_track",
        "obs_box",
        "obs_score",
        "keypoints",
        "confidence",
        "world",
        "colour",
    )
    return {name: getattr(chunk, name)[keep] for name in names}


def _join(previous: dict[str, np.ndarray], chunk: ChunkTracks, overlap: range) -> dict[int, int]:
    """Local track of ``chunk`` -> video track of ``previous`` rows, from the shared frames."""
    in_overlap = np.isin(chunk.obs_frame, overlap)
    local_ids = np.unique(chunk.obs_track[in_overlap])
    video_ids = np.unique(previous["obs_track"][np.isin(previous["obs_frame"], overlap)])
    if not len(local_ids) or not len(video_ids):
        return {}
    mean_iou = np.zeros((len(local_ids), len(video_ids)))
    for a, local in enumerate(local_ids):
        mine = in_overlap & (chunk.obs_track == local)
        boxes = dict(zip(chunk.obs_frame[mine].tolist(), chunk.obs_box[mine], strict=True))
        for b, video in enumerate(video_ids):
            theirs = (previous["obs_track"] == video) & np.isin(previous["obs_frame"], overlap)
            ious = [
                box_iou(boxes[f], box[None])[0]
                for f, box in zip(
                    previous["obs_frame"][theirs], previous["obs_box"][theirs], strict=True
                )
                if f in boxes
            ]
            mean_iou[a, b] = np.mean(ious) if ious else 0.0
    cost = np.where(mean_iou >= JOIN_IOU, 1.0 - mean_iou, np.inf)
    rows, cols = hungarian(cost)
    return {int(local_ids[r]): int(video_ids[c]) for r, c in zip(rows, cols, strict=True)}


def merge_chunks(spans: list[ChunkSpan], chunks: list[ChunkTracks]) -> VideoTracks:
    """The chunks of one video, in frame order, joined into one :class:`VideoTracks`."""
    if len(spans) != len(chunks):
        raise ValueError(f"{len(spans)} chunk spans but {len(chunks)} chunk results")
    parts: list[dict[str, np.ndarray]] = []
    dets: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    track_shot: list[int] = []
    previous: dict[str, np.ndarray] | None = None
    previous_span: ChunkSpan | None = None
    for span, chunk in zip(spans, chunks, strict=True):
        joined: dict[int, int] = {}
        if (
            previous is not None
            and previous_span.shot == span.shot
            and span.read_start < span.start
        ):
            joined = _join(previous, chunk, range(span.read_start, span.start))
        own = chunk.obs_frame >= span.start
        rows = _rows(chunk, own)
        mapping = {}
        for local in sorted(
            set(rows["obs_track"].tolist()),
            key=lambda t: (rows["obs_frame"][rows["obs_track"] == t].min(), t),
        ):
            if local in joined:
                mapping[local] = joined[local]
            else:
                mapping[local] = len(track_shot)
                track_shot.append(span.shot)
        rows["obs_track"] = np.array([mapping[t] for t in rows["obs_track"].tolist()], np.int64)
        parts.append(rows)
        keep = chunk.det_frame >= span.start
        dets.append((chunk.det_frame[keep], chunk.det_box[keep], chunk.det_score[keep]))
        previous, previous_span = rows, span
    # A chunk where nobody was seen has no joint axis to speak of (J = 0): it adds no rows.
    seen = [p for p in parts if len(p["obs_frame"])] or parts[:1]
    merged = {name: np.concatenate([p[name] for p in seen]) for name in parts[0]}
    return VideoTracks(
        det_frame=np.concatenate([d[0] for d in dets]),
        det_box=np.concatenate([d[1] for d in dets]),
        det_score=np.concatenate([d[2] for d in dets]),
        track_shot=np.array(track_shot, np.int64),
        **merged,
    )


def summaries(tracks: VideoTracks) -> list[TrackSummary]:
    """One :class:`TrackSummary` per video track, for choosing the fighters."""
    found = []
    for track in range(len(tracks.track_shot)):
        mine = tracks.obs_track == track
        frames = tracks.obs_frame[mine]
        if not len(frames):
            continue
        first, last = int(frames.min()), int(frames.max())
        boxes = np.full((last - first + 1, 4), np.nan)
        scores = np.full(last - first + 1, np.nan)
        boxes[frames - first] = tracks.obs_box[mine]
        scores[frames - first] = tracks.obs_score[mine]
        observed = box_to_cxcywh(tracks.obs_box[mine])
        found.append(
            TrackSummary(
                track_id=track,
                first_frame=first,
                last_frame=last,
                frames_observed=len(frames),
                mean_size=observed[:, 2:].mean(axis=0),
                mean_centre=observed[:, :2].mean(axis=0),
                colour=tracks.colour[mine].mean(axis=0),
                boxes=boxes,
                scores=scores,
            )
        )
    return found
