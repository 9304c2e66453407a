"""Choosing the two fighters among the tracks, joining a fighter's fragments, and telling which
fighter is the adversary from the colour the analyst declared.

All functions take the :class:`~tasks.pose.people_tracking.TrackSummary` list a tracker
produced for one shot (or any span of frames) and are pure.
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass

import cv2
import numpy as np

from tasks.pose.config import FighterConfig
from tasks.pose.people_tracking import (
    DESCRIPTOR_SIZE,
    HUE_BINS,
    MIN_SATURATION,
    MIN_VALUE,
    PART_BINS,
    SAT_BINS,
    VALUE_BINS,
    TrackSummary,
    colour_distances,
    hsv_bins,
    hungarian,
)


def track_scores(
    tracks: list[TrackSummary], frame_size: tuple[int, int], num_frames: int, config: FighterConfig
) -> np.ndarray:
    """(T,) score in [0, 1] of each track as a fighter: weighted presence, size, centrality."""
    width, height = frame_size
    presence = np.array([t.frames_observed / num_frames for t in tracks])
    heights = np.array([t.mean_size[1] for t in tracks])
    size = heights / heights.max()
    offset = np.array([t.mean_centre for t in tracks]) - np.array([width, height]) / 2
    centre = 1.0 - np.minimum(np.linalg.norm(offset / (np.array([width, height]) / 2), axis=1), 1)
    weights = np.array([config.presence_weight, config.size_weight, config.centre_weight])
    terms = np.stack([np.minimum(presence, 1.0), size, centre], axis=1)
    return terms @ weights / weights.sum()


def pair_terms(
    a: TrackSummary, b: TrackSummary, num_frames: int, config: FighterConfig
) -> tuple[float, float, float] | None:
    """(similar size, together, near) terms of a pair, each in [0, 1]; None if never seen
    together (two tracks that never share a frame are not two fighters, maybe one person)."""
    start, stop = max(a.first_frame, b.first_frame), min(a.last_frame, b.last_frame) + 1
    if stop <= start:
        return None
    boxes_a = a.boxes[start - a.first_frame : stop - a.first_frame]
    boxes_b = b.boxes[start - b.first_frame : stop - b.first_frame]
    both = ~np.isnan(boxes_a[:, 0]) & ~np.isnan(boxes_b[:, 0])
    if not both.any():
        return None
    centre_a = (boxes_a[both, :2] + boxes_a[both, 2:]) / 2
    centre_b = (boxes_b[both, :2] + boxes_b[both, 2:]) / 2
    mean_height = (a.mean_size[1] + b.mean_size[1]) / 2
    distance = np.linalg.norm(centre_a - centre_b, axis=1).mean() / mean_height
    similar = min(a.mean_size[1], b.mean_size[1]) / max(a.mean_size[1], b.mean_size[1])
    together = min(both.sum() / num_frames, 1.0)
    near = max(0.0, 1.0 - distance / config.near_scale)
    return float(similar), float(together), float(near)


# Two boxes overlapping this much in one frame sit on one body (issue 33: two tracks that
# collapsed onto one pedestrian overlapped by a median IoU of 0.988).
ONE_BODY_IOU = 0.8


@dataclass(frozen=True)
class PairScore:
    """A candidate pair of fighters: its score, its two track ids (ascending), the share of
    the span's frames in which both are seen, and the share of those in which their boxes sit
    on one body (IoU above ONE_BODY_IOU: one person tracked twice, not two fighters)."""

    score: float
    track_ids: tuple[int, int]
    together: float
    one_body: float = 0.0


def one_body_share(a: TrackSummary, b: TrackSummary) -> float:
    """Share of the frames where both tracks are observed in which their boxes overlap by more
    than ONE_BODY_IOU; 0 if never seen together."""
    start, stop = max(a.first_frame, b.first_frame), min(a.last_frame, b.last_frame) + 1
    if stop <= start:
        return 0.0
    boxes_a = a.boxes[start - a.first_frame : stop - a.first_frame]
    boxes_b = b.boxes[start - b.first_frame : stop - b.first_frame]
    both = ~np.isnan(boxes_a[:, 0]) & ~np.isnan(boxes_b[:, 0])
    if not both.any():
        return 0.0
    low = np.maximum(boxes_a[both, :2], boxes_b[both, :2])
    high = np.minimum(boxes_a[both, 2:], boxes_b[both, 2:])
    inter = np.prod(np.clip(high - low, 0, None), axis=1)
    area = np.prod(boxes_a[both, 2:] - boxes_a[both, :2], axis=1) + np.prod(
        boxes_b[both, 2:] - boxes_b[both, :2], axis=1
    )
    return float(np.mean(inter / (area - inter) > ONE_BODY_IOU))


def rank_pairs(
    tracks: list[TrackSummary],
    frame_size: tuple[int, int],
    *,
    num_frames: int | None = None,
    config: FighterConfig | None = None,
) -> list[PairScore]:
    """Every pair of tracks seen together in at least one frame, best first.

    A pair's score is the mean of its two :func:`track_scores` (presence, size, centrality) plus
    the weighted mean of its :func:`pair_terms` (similar size, together, near).

    Args:
        tracks: the tracks of one span of frames (e.g. a shot).
        frame_size: (width, height) of the frames in pixels.
        num_frames: frames in the span; default from the first to the last frame any track saw.
        config: the weights; default :class:`FighterConfig`.
    """
    config = config or FighterConfig()
    width, height = _check_frame_size(frame_size)
    if not tracks:
        return []
    num_frames = _span(tracks, num_frames)
    single = track_scores(tracks, (width, height), num_frames, config)
    pair_weights = np.array(
        [config.similar_size_weight, config.together_weight, config.near_weight]
    )
    ranked = []
    for i, j in itertools.combinations(range(len(tracks)), 2):
        terms = pair_terms(tracks[i], tracks[j], num_frames, config)
        if terms is None:
            continue
        bonus = np.dot(terms, pair_weights) / pair_weights.sum() if pair_weights.sum() else 0.0
        ids = sorted([tracks[i].track_id, tracks[j].track_id])
        score = float((single[i] + single[j]) / 2 + bonus)
        ranked.append(PairScore(score, tuple(ids), terms[1], one_body_share(tracks[i], tracks[j])))
    # Ties keep the order of the tracks, as the first pair found used to win.
    return sorted(ranked, key=lambda p: -p.score)


def pick_fighters(
    tracks: list[TrackSummary],
    frame_size: tuple[int, int],
    *,
    num_frames: int | None = None,
    config: FighterConfig | None = None,
) -> list[int]:
    """Ids of the (up to) two tracks that are the fighters, referee and crowd left out: the best
    pair of :func:`rank_pairs`.

    Returns:
        The two ids in ascending order; one id if no two tracks are ever seen together (the
        best single track); [] if there are no tracks.
    """
    ranked = rank_pairs(tracks, frame_size, num_frames=num_frames, config=config)
    if ranked:
        return list(ranked[0].track_ids)
    if not tracks:
        return []
    single = track_scores(
        tracks, _check_frame_size(frame_size), _span(tracks, num_frames), config or FighterConfig()
    )
    return [tracks[int(np.argmax(single))].track_id]


def _span(tracks: list[TrackSummary], num_frames: int | None) -> int:
    """``num_frames``, by default from the first to the last frame any track saw."""
    if num_frames is None:
        num_frames = max(t.last_frame for t in tracks) - min(t.first_frame for t in tracks) + 1
    if num_frames < 1:
        raise ValueError(f"num_frames must be at least 1, got {num_frames}")
    return num_frames


def choice_margin(ranked: list[PairScore]) -> float:
    """How clearly the best pair beat the next: (best - second) / best score; NaN when only
    one pair qualified (there was nothing to beat, which is no sign of a clear choice), 0 with
    no pair at all."""
    if not ranked:
        return 0.0
    if len(ranked) == 1:
        return float("nan")
    if ranked[0].score <= 0:
        return 0.0
    return float((ranked[0].score - ranked[1].score) / ranked[0].score)


def link_fragments(
    tracks: list[TrackSummary],
    *,
    max_gap_frames: int,
    max_distance: float = 1.0,
    far_distance: float = 4.0,
    max_colour_distance: float = 0.3,
    alpha: float = 0.5,
) -> tuple[list[TrackSummary], dict[int, int]]:
    """Join tracks that are one person broken in pieces (the tracker lost them too long).

    A track that ends at frame e may continue as one that starts at frame s, e < s <= e +
    max_gap_frames, when the later one's first box is near the earlier one's last centre or
    that centre carried on at its final velocity, and their mean colours differ by at most
    ``max_colour_distance``. Near is within a reach of ``max_distance`` box heights at once,
    widening linearly to ``far_distance`` at a gap of ``max_gap_frames``: someone unseen for a
    while may have gone further (jumped down from a box, run behind the others), where no
    velocity from before says. Among such candidates, ends are paired with starts by
    :func:`~tasks.pose.people_tracking.hungarian` on ``alpha * distance / reach + (1 - alpha) *
    colour distance``; chains of pieces become one track with the first piece's id.

    Returns:
        The tracks after joining, by id, and a mapping from every input id to its id after.
    """
    if max_gap_frames < 1:
        raise ValueError(f"max_gap_frames must be at least 1, got {max_gap_frames}")
    if not 0 < max_distance <= far_distance:
        raise ValueError(
            f"max_distance must be positive and at most far_distance ({far_distance}), "
            f"got {max_distance}"
        )
    ordered = sorted(tracks, key=lambda t: t.track_id)
    n = len(ordered)
    cost = np.full((n, n), np.inf)
    descriptors = np.array([t.colour for t in ordered]).reshape(n, DESCRIPTOR_SIZE)
    colour = colour_distances(descriptors, descriptors)
    for i, j in itertools.product(range(n), range(n)):
        earlier, later = ordered[i], ordered[j]
        gap = later.first_frame - earlier.last_frame
        if not 0 < gap <= max_gap_frames or colour[i, j] > max_colour_distance:
            continue
        last, velocity = _end_motion(earlier)
        start = _centre(later.boxes[0])
        distance = (
            min(np.linalg.norm(start - last), np.linalg.norm(start - (last + velocity * gap)))
            / earlier.mean_size[1]
        )
        reach = max_distance + (far_distance - max_distance) * gap / max_gap_frames
        if distance <= reach:
            cost[i, j] = alpha * distance / reach + (1 - alpha) * colour[i, j]
    rows, cols = hungarian(cost)
    after = dict(zip(rows.tolist(), cols.tolist(), strict=True))
    heads = sorted(set(range(n)) - set(after.values()))
    joined, mapping = [], {}
    for head in heads:
        chain = [head]
        while chain[-1] in after:
            chain.append(after[chain[-1]])
        pieces = [ordered[k] for k in chain]
        joined.append(_join(pieces))
        mapping |= {p.track_id: pieces[0].track_id for p in pieces}
    return sorted(joined, key=lambda t: t.track_id), mapping


def _centre(box: np.ndarray) -> np.ndarray:
    return (box[:2] + box[2:]) / 2


def _end_motion(track: TrackSummary, frames: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """(2,) last observed centre and (2,) velocity in pixels per frame over its last observed
    ``frames`` frames (a least-squares line; zero with one observation)."""
    seen = np.flatnonzero(track.observed)[-frames:]
    centres = (track.boxes[seen, :2] + track.boxes[seen, 2:]) / 2
    if len(seen) < 2:
        return centres[-1], np.zeros(2)
    t = seen - seen.mean()
    velocity = (t[:, None] * (centres - centres.mean(axis=0))).sum(axis=0) / (t**2).sum()
    return centres[-1], velocity


def _join(pieces: list[TrackSummary]) -> TrackSummary:
    """One track from time-ordered, non-overlapping pieces of the same person."""
    if len(pieces) == 1:
        return pieces[0]
    first, last = pieces[0].first_frame, pieces[-1].last_frame
    boxes = np.full((last - first + 1, 4), np.nan)
    scores = np.full(last - first + 1, np.nan)
    for p in pieces:
        boxes[p.first_frame - first : p.last_frame - first + 1] = p.boxes
        scores[p.first_frame - first : p.last_frame - first + 1] = p.scores
    weights = np.array([p.frames_observed for p in pieces], dtype=np.float64)

    def mean(name: str) -> np.ndarray:
        return np.average([getattr(p, name) for p in pieces], axis=0, weights=weights)

    return TrackSummary(
        track_id=pieces[0].track_id,
        first_frame=first,
        last_frame=last,
        frames_observed=int(weights.sum()),
        mean_size=mean("mean_size"),
        mean_centre=mean("mean_centre"),
        colour=mean("colour"),
        boxes=boxes,
        scores=scores,
    )


def colour_template(colour_hex: str) -> np.ndarray:
    """(PART_BINS,) weights in [0, 1] of the descriptor bins a garment of this colour fills.

    A coloured garment (saturation and brightness above the tracker's limits) fills its hue bin
    (weight 1) and the two neighbouring hues (0.5), at its saturation and the next ones (1) or
    any other saturation (0.5): light and shade move a fabric's saturation more than its hue.
    Black, white and grey have no hue: they fill their brightness bin (1) and its neighbours
    (0.5), which is how black trunks are told from white ones.
    """
    if not isinstance(colour_hex, str) or not re.fullmatch(r"#[0-9a-fA-F]{6}", colour_hex):
        raise ValueError(f"colour_hex must look like '#rrggbb', got {colour_hex!r}")
    rgb = [int(colour_hex[k : k + 2], 16) for k in (1, 3, 5)]
    hsv = cv2.cvtColor(np.array([[rgb[::-1]]], dtype=np.uint8), cv2.COLOR_BGR2HSV)[0, 0]
    weights = np.zeros(PART_BINS)
    bin_ = int(hsv_bins(hsv))
    if hsv[1] >= MIN_SATURATION and hsv[2] >= MIN_VALUE:
        hue, sat = divmod(bin_, SAT_BINS)
        for h_step, s in itertools.product((-1, 0, 1), range(SAT_BINS)):
            h_weight = 1.0 if h_step == 0 else 0.5
            s_weight = 1.0 if abs(s - sat) <= 1 else 0.5
            weights[((hue + h_step) % HUE_BINS) * SAT_BINS + s] = h_weight * s_weight
    else:
        value = bin_ - HUE_BINS * SAT_BINS
        for step in (-1, 0, 1):
            if 0 <= value + step < VALUE_BINS:
                weights[HUE_BINS * SAT_BINS + value + step] = 1.0 if step == 0 else 0.5
    return weights


def adversary_by_colour(tracks: list[TrackSummary], fighter_ids: list[int], colour_hex: str) -> int:
    """The fighter wearing the declared colour (trunks or shirt, '#rrggbb').

    Each fighter's mean colour descriptor is weighed against :func:`colour_template` in its upper
    part (shirt) and its lower part (trunks); the fighter whose better part holds the most
    weighted mass wins, the first of ``fighter_ids`` on a tie.
    """
    template = colour_template(colour_hex)
    if not fighter_ids:
        raise ValueError("fighter_ids must name at least one track, got none")
    by_id = {t.track_id: t for t in tracks}
    missing = [i for i in fighter_ids if i not in by_id]
    if missing:
        raise ValueError(f"fighter_ids {missing} are not among the tracks' ids {sorted(by_id)}")
    scores = [
        float((np.asarray(by_id[i].colour).reshape(2, PART_BINS) @ template).max())
        for i in fighter_ids
    ]
    return fighter_ids[int(np.argmax(scores))]


def _check_frame_size(frame_size: tuple[int, int]) -> tuple[int, int]:
    if len(frame_size) != 2 or not all(
        isinstance(v, int | np.integer) and v > 0 for v in frame_size
    ):
        raise ValueError(f"frame_size must be (width, height) positive ints, got {frame_size!r}")
    return int(frame_size[0]), int(frame_size[1])
