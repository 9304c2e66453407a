"""Tracking people across frames: assignment, box motion, clothing colour and the tracker.

The pose stage detects people in every frame; this module links those detections into tracks
that keep one id per person through crossings, short occlusions and missed detections:

- motion: a constant-velocity Kalman filter on each box (:class:`BoxKalman`);
- appearance: hue-saturation histograms of the upper and lower half of the box, i.e. shirt or
  torso versus trunks (:func:`appearance`), compared with the Bhattacharyya distance;
- association: the boxing pose thesis's mix ``cost = alpha * d_s + (1 - alpha) * d_c`` of a
  position distance and a clothing-colour distance, solved optimally by :func:`hungarian`,
  high-scoring detections first and weak ones second (ByteTrack, Zhang et al. 2022).

Coordinates are image pixels, x right and y down; boxes are (4,) x0, y0, x1, y1. Shape letters:
T tracks, O observations, D colour descriptor length (:data:`DESCRIPTOR_SIZE`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Hashable, Iterable, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from models.pose.boxes import box_areas, covered_shares, intersections
from models.pose.types import Detection
from tasks.pose.config import TrackerConfig

# ---------------------------------------------------------------------------------------------
# Optimal assignment


def hungarian(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-cost assignment between the rows and columns of a rectangular cost matrix, with
    forbidden pairs (scipy's `linear_sum_assignment` on a matrix where they cost more than any
    allowed set).

    Args:
        cost: (N, M) float costs; ``np.inf`` marks a forbidden pair.

    Returns:
        ``(rows, cols)``, two (K,) int arrays, rows ascending: row ``rows[k]`` goes with column
        ``cols[k]``. The pairs use as many allowed pairs as possible and, among such sets, have
        the least total cost; with nothing forbidden K = min(N, M). No forbidden pair is ever
        returned.
    """
    cost = np.asarray(cost, dtype=np.float64)
    if cost.ndim != 2:
        raise ValueError(f"cost must be a 2-D (N, M) array, got shape {cost.shape}")
    if np.isnan(cost).any() or np.isneginf(cost).any():
        raise ValueError("cost must hold finite numbers or +inf (forbidden), got NaN or -inf")
    empty = np.zeros(0, dtype=np.int64)
    allowed = np.isfinite(cost)
    if not allowed.any():
        return empty, empty.copy()
    low, high = cost[allowed].min(), cost[allowed].max()
    scaled = (cost - low) / (high - low) if high > low else np.zeros_like(cost)
    # Allowed costs now lie in [0, 1]; a forbidden pair costing more than K allowed pairs together
    # makes the optimum use as few forbidden pairs as possible first, and only then save cost.
    big = min(cost.shape) + 1.0
    rows, cols = linear_sum_assignment(np.where(allowed, scaled, big))
    keep = allowed[rows, cols]
    return rows[keep].astype(np.int64), cols[keep].astype(np.int64)


# ---------------------------------------------------------------------------------------------
# Box motion


def box_to_cxcywh(box: np.ndarray) -> np.ndarray:
    """(..., 4) x0, y0, x1, y1 boxes as (..., 4) centre x, centre y, width, height."""
    box = np.asarray(box, dtype=np.float64)
    size = box[..., 2:] - box[..., :2]
    return np.concatenate([box[..., :2] + size / 2, size], axis=-1)


def cxcywh_to_box(cxcywh: np.ndarray) -> np.ndarray:
    """(..., 4) centre x, centre y, width, height as (..., 4) x0, y0, x1, y1 boxes."""
    cxcywh = np.asarray(cxcywh, dtype=np.float64)
    half = cxcywh[..., 2:] / 2
    return np.concatenate([cxcywh[..., :2] - half, cxcywh[..., :2] + half], axis=-1)


@dataclass(frozen=True, eq=False)
class BoxState:
    """Kalman estimate of one box.

    Attributes:
        mean: (8,) cx, cy, w, h in pixels and their velocities in pixels per frame.
        covariance: (8, 8) covariance of ``mean``.
    """

    mean: np.ndarray
    covariance: np.ndarray

    def box(self) -> np.ndarray:
        """(4,) x0, y0, x1, y1 of the estimated box."""
        return cxcywh_to_box(self.mean[:4])


_TRANSITION = np.block([[np.eye(4), np.eye(4)], [np.zeros((4, 4)), np.eye(4)]])  # one frame
_MEASURE = np.hstack([np.eye(4), np.zeros((4, 4))])


@dataclass(frozen=True)
class BoxKalman:
    """Constant-velocity Kalman filter on a box's centre, width and height, one step per frame.

    The state is (cx, cy, w, h) and their velocities, as in BoT-SORT (Aharon et al. 2022), which
    tracks the width itself rather than SORT's area and fixed aspect or ByteTrack's aspect ratio:
    a boxer's aspect changes with every punch, and a width estimate follows that better.
    Process and measurement noise are standard deviations proportional to the box's own width
    (x, w) or height (y, h), as in DeepSORT and ByteTrack, so the filter behaves the same for a
    fighter near the camera and one far from it. Every method returns a new state.
    """

    position_noise: float = 1 / 20
    velocity_noise: float = 1 / 160

    def _size(self, mean: np.ndarray) -> np.ndarray:
        w, h = max(mean[2], 1.0), max(mean[3], 1.0)
        return np.array([w, h, w, h])

    def start(self, box: np.ndarray) -> BoxState:
        """State for a box first seen now: its position, zero velocity, wide uncertainty."""
        measured = box_to_cxcywh(box)
        size = self._size(measured)
        std = np.concatenate([2 * self.position_noise * size, 10 * self.velocity_noise * size])
        mean = np.concatenate([measured, np.zeros(4)])
        return BoxState(mean, np.diag(std**2))

    def predict(self, state: BoxState) -> BoxState:
        """The state one frame later, before seeing that frame."""
        size = self._size(state.mean)
        noise = np.diag(np.concatenate([self.position_noise * size, self.velocity_noise * size]))
        mean = _TRANSITION @ state.mean
        mean[2:4] = np.maximum(mean[2:4], 1.0)  # a long coast must not shrink a box to nothing
        covariance = _TRANSITION @ state.covariance @ _TRANSITION.T + noise**2
        return BoxState(mean, covariance)

    def update(self, state: BoxState, box: np.ndarray) -> BoxState:
        """``state`` corrected by the box (4,) x0, y0, x1, y1 observed in the same frame."""
        noise = np.diag(self.position_noise * self._size(state.mean)) ** 2
        innovation_cov = _MEASURE @ state.covariance @ _MEASURE.T + noise
        gain = np.linalg.solve(innovation_cov, _MEASURE @ state.covariance).T
        mean = state.mean + gain @ (box_to_cxcywh(box) - _MEASURE @ state.mean)
        covariance = state.covariance - gain @ _MEASURE @ state.covariance
        return BoxState(mean, (covariance + covariance.T) / 2)


# ---------------------------------------------------------------------------------------------
# Clothing colour

HUE_BINS, SAT_BINS, VALUE_BINS = 16, 4, 8
PART_BINS = HUE_BINS * SAT_BINS + VALUE_BINS
DESCRIPTOR_SIZE = 2 * PART_BINS
# Pixels this grey or dark have no reliable hue; they fall into brightness-only bins instead,
# which is what tells black trunks from white (Perez et al. 2002, colour-based tracking).
MIN_SATURATION, MIN_VALUE = 64, 51
# Fractions of the box used: the central 60% of the width (the sides are mostly background);
# upper part rows 10-50% (torso or shirt, below most of the head), lower part rows 50-90%
# (trunks and thighs, above the floor).
_INSET_X = 0.2
_PARTS = ((0.1, 0.5), (0.5, 0.9))
_SAMPLES = 4096  # pixels sampled per part at most: a histogram needs no more


def hsv_bins(hsv: np.ndarray) -> np.ndarray:
    """Descriptor bin, in 0..PART_BINS-1, of each OpenCV HSV pixel (H 0-179, S and V 0-255).

    Args:
        hsv: (..., 3) uint8 HSV pixels.

    Returns:
        (...,) int bins: ``hue * SAT_BINS + saturation`` for coloured pixels, with hue bins
        centred on 0 so pure red falls in the middle of bin 0; ``HUE_BINS * SAT_BINS + value``
        for grey, black and white pixels.
    """
    hsv = np.asarray(hsv).astype(np.int64)
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    hue = (h * HUE_BINS + 90) // 180 % HUE_BINS
    sat = np.minimum((s - MIN_SATURATION) * SAT_BINS // (256 - MIN_SATURATION), SAT_BINS - 1)
    value = v * VALUE_BINS // 256
    coloured = (s >= MIN_SATURATION) & (v >= MIN_VALUE)
    return np.where(coloured, hue * SAT_BINS + np.maximum(sat, 0), HUE_BINS * SAT_BINS + value)


def appearance(image_bgr: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Clothing-colour descriptor of the person in ``box``.

    The boxing pose thesis tells fighters apart by clothing colour; here that is a histogram of
    the upper half (torso or shirt) and one of the lower half (trunks) of the box, each over
    hue x saturation bins plus brightness bins for unsaturated pixels (see :func:`hsv_bins`),
    each L1-normalised, concatenated.

    Args:
        image_bgr: (H, W, 3) uint8 BGR frame.
        box: (4,) x0, y0, x1, y1 person box in pixels; parts outside the image are ignored.

    Returns:
        (DESCRIPTOR_SIZE,) float32: upper part's PART_BINS then lower part's, each summing to
        1, or all zero where that part of the box has no pixel inside the image.
    """
    image = np.asarray(image_bgr)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(
            f"image_bgr must be an (H, W, 3) uint8 BGR image, got {image.dtype} {image.shape}"
        )
    box = _check_box("box", box)
    x0, y0, x1, y1 = box
    width, height = x1 - x0, y1 - y0
    cols = _clip_span(x0 + _INSET_X * width, x1 - _INSET_X * width, image.shape[1])
    parts = []
    for top, bottom in _PARTS:
        rows = _clip_span(y0 + top * height, y0 + bottom * height, image.shape[0])
        hist = np.zeros(PART_BINS, dtype=np.float32)
        if rows[1] > rows[0] and cols[1] > cols[0]:
            area = (rows[1] - rows[0]) * (cols[1] - cols[0])
            step = max(1, math.ceil(math.sqrt(area / _SAMPLES)))
            crop = np.ascontiguousarray(image[rows[0] : rows[1] : step, cols[0] : cols[1] : step])
            bins = hsv_bins(cv2.cvtColor(crop, cv2.COLOR_BGR2HSV)).ravel()
            hist = np.bincount(bins, minlength=PART_BINS).astype(np.float32)
            hist /= hist.sum()
        parts.append(hist)
    return np.concatenate(parts)


def _clip_span(start: float, stop: float, size: int) -> tuple[int, int]:
    return max(0, int(round(start))), min(size, int(round(stop)))


def colour_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise clothing-colour distance in [0, 1] between two sets of descriptors.

    Per part, the Bhattacharyya (Hellinger) distance ``sqrt(1 - sum_i sqrt(p_i q_i))`` of the
    two histograms; the two parts' distances are averaged. A part that is empty in either
    descriptor tells nothing and counts as 0.5.

    Args:
        a: (T, D) descriptors from :func:`appearance` (or averages of them).
        b: (O, D) descriptors.

    Returns:
        (T, O) float distances.
    """
    a = np.asarray(a, dtype=np.float64).reshape(-1, 2, PART_BINS)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 2, PART_BINS)
    distance = np.empty((len(a), len(b), 2))
    for part in range(2):
        p, q = a[:, part], b[:, part]
        overlap = np.sqrt(np.clip(p, 0, None)) @ np.sqrt(np.clip(q, 0, None)).T
        distance[..., part] = np.sqrt(np.clip(1.0 - overlap, 0.0, 1.0))
        empty = (p.sum(axis=1) <= 0)[:, None] | (q.sum(axis=1) <= 0)[None, :]
        distance[..., part][empty] = 0.5
    return distance.mean(axis=2)


def colour_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Clothing-colour distance in [0, 1] between two (D,) descriptors (see colour_distances)."""
    return float(colour_distances(_check_colour("a", a), _check_colour("b", b))[0, 0])


# ---------------------------------------------------------------------------------------------
# The tracker


@dataclass(frozen=True, eq=False)
class Observation:
    """One detected person in one frame, as the tracker takes it.

    Attributes:
        box: (4,) float x0, y0, x1, y1 in pixels, x1 > x0 and y1 > y0.
        score: detector confidence in 0..1.
        colour: (DESCRIPTOR_SIZE,) clothing-colour descriptor from :func:`appearance`.
        keypoints: (J, 2) the pose's keypoints in pixels, or None (a detection without a pose):
            with them two overlapping observations are told to be one body or two.
    """

    box: np.ndarray
    score: float
    colour: np.ndarray
    keypoints: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "box", _check_box("Observation.box", self.box))
        object.__setattr__(self, "colour", _check_colour("Observation.colour", self.colour))
        if self.keypoints is not None:
            keypoints = np.asarray(self.keypoints, dtype=np.float64)
            if keypoints.ndim != 2 or keypoints.shape[1] != 2:
                raise ValueError(
                    f"Observation.keypoints must be (J, 2) pixels, got shape {keypoints.shape}"
                )
            object.__setattr__(self, "keypoints", keypoints)
        if not math.isfinite(self.score):
            raise ValueError(f"Observation.score must be a finite number, got {self.score}")


def observations(image_bgr: np.ndarray, detections: Iterable[Detection]) -> list[Observation]:
    """The detections of one (H, W, 3) uint8 BGR frame as observations, colour measured."""
    return [Observation(d.box, float(d.score), appearance(image_bgr, d.box)) for d in detections]


@dataclass(frozen=True, eq=False)
class TrackSummary:
    """What a track saw over its life; frames are the tracker's frame indices.

    Attributes:
        track_id: the id, from 0 in the order tracks were confirmed.
        first_frame, last_frame: first and last frame in which the track was observed.
        frames_observed: how many frames in between it was observed (not coasting).
        mean_size: (2,) mean observed box width and height, pixels.
        mean_centre: (2,) mean observed box centre x, y, pixels.
        colour: (DESCRIPTOR_SIZE,) mean colour descriptor of its clean observations (all of
            them if none was clean).
        boxes: (last_frame - first_frame + 1, 4) observed box per frame, NaN rows where unseen.
        scores: (last_frame - first_frame + 1,) detection score per frame, NaN where unseen.
    """

    track_id: int
    first_frame: int
    last_frame: int
    frames_observed: int
    mean_size: np.ndarray
    mean_centre: np.ndarray
    colour: np.ndarray
    boxes: np.ndarray
    scores: np.ndarray

    @property
    def observed(self) -> np.ndarray:
        """(last_frame - first_frame + 1,) bool, True in frames where the track was observed."""
        return ~np.isnan(self.scores)


@dataclass
class _Track:
    """A track's working state inside :class:`Tracker` (mutable, never handed out)."""

    state: BoxState
    colour: np.ndarray
    first_frame: int
    last_frame: int
    hits: int = 0  # consecutive frames observed; tentative tracks never miss one
    track_id: int | None = None
    frames: list[int] = field(default_factory=list)
    boxes: list[np.ndarray] = field(default_factory=list)
    scores: list[float] = field(default_factory=list)
    clean_colours: list[np.ndarray] = field(default_factory=list)
    all_colours: list[np.ndarray] = field(default_factory=list)


def association_cost(
    predicted: np.ndarray,
    frames_unseen: np.ndarray,
    track_colours: np.ndarray,
    boxes: np.ndarray,
    colours: np.ndarray,
    config: TrackerConfig,
    fps: float,
) -> np.ndarray:
    """Cost of giving each observation to each track, ``inf`` where gated out.

    d_s is the distance between the predicted and observed box centres in predicted box
    heights, over the gate ``config.gate_distance``; pairs with d_s > 1 are forbidden. Centre
    distance rather than 1 - IoU: IoU is 0 for every box that does not overlap the prediction,
    so after a coast (when the prediction has drifted) it cannot rank candidates, while the
    centre distance still can; in heights, it reads the same near and far from the camera. A
    coasting track's gate widens by ``gate_growth_per_s`` of itself per second unseen, and d_s
    is measured against the widened gate: like a Mahalanobis distance, a pixel counts for less
    where the position is less certain. d_c is :func:`colour_distances`. Pairs costing more
    than ``config.max_cost`` are forbidden too, so that the matching, which makes as many pairs
    as it can, never pairs someone with a track merely because both were left over.

    Args:
        predicted: (T, 4) predicted track boxes.
        frames_unseen: (T,) frames since each track was last observed (1 = seen last frame).
        track_colours: (T, D) track colour descriptors.
        boxes: (O, 4) observed boxes.
        colours: (O, D) observed colour descriptors.
        config, fps: the tracker's config and the video's frame rate.

    Returns:
        (T, O) ``alpha * d_s + (1 - alpha) * d_c``, ``inf`` for forbidden pairs.
    """
    pred = box_to_cxcywh(predicted)
    obs = box_to_cxcywh(boxes)
    height = pred[:, 3:4]
    distance = np.linalg.norm(pred[:, None, :2] - obs[None, :, :2], axis=2) / height
    widen = 1.0 + config.gate_growth_per_s / fps * np.maximum(frames_unseen - 1, 0)
    d_s = distance / (config.gate_distance * widen[:, None])
    d_c = colour_distances(track_colours, colours)
    cost = config.alpha * d_s + (1.0 - config.alpha) * d_c
    ratio = obs[None, :, 3] / height
    allowed = (
        (d_s <= 1.0)
        & (d_c <= config.max_colour_distance)
        & (cost <= config.max_cost)
        & (ratio <= config.max_height_ratio)
        & (ratio >= 1.0 / config.max_height_ratio)
    )
    return np.where(allowed, cost, np.inf)


class Tracker:
    """Online multi-person tracker: feed it each frame's observations in order.

    Per frame (:meth:`update`): every live track's Kalman state is predicted one frame on;
    observations scoring at least ``high_score`` are matched to all live tracks, then those in
    ``[low_score, high_score)`` to the confirmed tracks left over, each by :func:`hungarian` on
    :func:`association_cost` (a track placed at its prediction or its last box, whichever
    fits better: :meth:`_cost`); matched tracks take a Kalman update; unmatched strong
    observations that duplicate no used one start tentative tracks; a tentative track missed
    once is dropped, a confirmed one unseen for more than ``max_coast_s`` ends. Call
    :meth:`cut` at a shot cut.
    """

    def __init__(self, config: TrackerConfig, fps: float, *, start_frame: int = 0) -> None:
        """config: the tracking settings; fps: frames per second of the video (turns the
        config's seconds into frames); start_frame: the index of the first frame fed."""
        if not (isinstance(fps, int | float) and math.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be a positive number, got {fps!r}")
        self.config = config
        self.fps = float(fps)
        self._kalman = BoxKalman(config.position_noise, config.velocity_noise)
        self._max_coast = round(config.max_coast_s * fps)
        self._frame = start_frame
        self._shot_start = start_frame
        self._live: list[_Track] = []
        self._ended: list[_Track] = []
        self._next_id = 0

    @property
    def frame(self) -> int:
        """Index of the frame the next :meth:`update` call is for."""
        return self._frame

    def predict(self) -> dict[int, np.ndarray]:
        """Where each live confirmed track expects to be in the next frame: id -> (4,) box.

        Includes coasting tracks (useful to crop a pose where the detector missed someone).
        Changes nothing.
        """
        return {
            t.track_id: self._kalman.predict(t.state).box()
            for t in self._live
            if t.track_id is not None
        }

    def update(self, observations: Sequence[Observation]) -> list[int | None]:
        """Take one frame's observations; return the track id given to each, in order.

        An entry is None when the observation went to no confirmed track: too weak, a
        duplicate, or the start of a track not yet confirmed (its frames are still recorded and
        appear in :meth:`tracks` once it is confirmed).
        """
        for i, o in enumerate(observations):
            if not isinstance(o, Observation):
                raise TypeError(f"observations[{i}] must be an Observation, got {type(o)}")
        cfg, frame = self.config, self._frame
        for track in self._live:
            track.state = self._kalman.predict(track.state)
        boxes = np.array([o.box for o in observations]).reshape(-1, 4)
        scores = np.array([o.score for o in observations])
        colours = np.array([o.colour for o in observations]).reshape(-1, DESCRIPTOR_SIZE)

        strong = [i for i in range(len(scores)) if scores[i] >= cfg.high_score]
        weak = [i for i in range(len(scores)) if cfg.low_score <= scores[i] < cfg.high_score]
        matches = self._associate(list(range(len(self._live))), strong, boxes, colours)
        left = [k for k in range(len(self._live)) if k not in matches.values()]
        left = [k for k in left if self._live[k].track_id is not None]
        matches |= self._associate(left, weak, boxes, colours)
        matches = self._one_track_per_body(matches, observations, boxes, colours)

        occluded = covered_shares(boxes).max(axis=1, initial=0.0) > cfg.occlusion_overlap
        given = {o: self._live[k] for o, k in matches.items()}  # observation -> its track
        for o in sorted(given):
            self._observe(given[o], frame, observations[o], occluded[o])

        # Unmatched strong observations, best first, start tracks unless they repeat a used box
        # or a body already taken.
        used = [boxes[o] for o in given]
        taken = [observations[o] for o in given]
        starters = []
        for o in sorted(set(strong) - set(given), key=lambda i: (-scores[i], i)):
            if used and _iou(boxes[o][None], np.array(used)).max() > cfg.duplicate_iou:
                continue
            if any(same_body(observations[o], t, cfg) for t in taken):
                continue
            taken.append(observations[o])
            used.append(boxes[o])
            if scores[o] >= cfg.new_track_score:
                starters.append(o)
        survivors, matched = [], set(matches.values())
        for k, track in enumerate(self._live):
            if k in matched:
                survivors.append(track)
            elif track.track_id is not None:
                if frame - track.last_frame <= self._max_coast:
                    survivors.append(track)
                else:
                    self._ended.append(track)
            # a tentative track missed even once is dropped: it was likely a false detection
        self._live = survivors
        for o in sorted(starters):
            state = self._kalman.start(boxes[o])
            given[o] = _Track(state, colours[o].copy(), frame, frame)
            self._observe(given[o], frame, observations[o], occluded[o])
            self._live.append(given[o])

        self._frame += 1
        return [given[o].track_id if o in given else None for o in range(len(scores))]

    def cut(self) -> None:
        """A shot cut: every live track ends here; people seen next get new ids."""
        self._ended.extend(t for t in self._live if t.track_id is not None)
        self._live = []
        self._shot_start = self._frame

    def tracks(self) -> list[TrackSummary]:
        """Every confirmed track so far, ended or live, by id."""
        confirmed = [t for t in self._ended + self._live if t.track_id is not None]
        return [_summarise(t) for t in sorted(confirmed, key=lambda t: t.track_id)]

    def _associate(
        self, track_index: list[int], obs_index: list[int], boxes: np.ndarray, colours: np.ndarray
    ) -> dict[int, int]:
        """Optimal matching of the given observations to the given live tracks: obs -> track."""
        if not track_index or not obs_index:
            return {}
        cost = self._cost(
            [self._live[k] for k in track_index], boxes[obs_index], colours[obs_index]
        )
        rows, cols = hungarian(cost)
        return {obs_index[c]: track_index[r] for r, c in zip(rows, cols, strict=True)}

    def _cost(self, tracks: list[_Track], boxes: np.ndarray, colours: np.ndarray) -> np.ndarray:
        """(T, O) :func:`association_cost` of ``tracks`` against observations, each track
        placed where its Kalman filter predicts it or where it was last seen, whichever fits
        better. A track coasting blind carries its last velocity on, and a person lost behind
        someone (a clinch) or standing still is found again where they were lost, not where
        that velocity drifted to (as OC-SORT, Cao et al. 2023, recovers a lost track at its last
        observation)."""
        unseen = np.array([self._frame - t.last_frame for t in tracks])
        track_colours = np.array([t.colour for t in tracks])
        cost = [
            association_cost(placed, unseen, track_colours, boxes, colours, self.config, self.fps)
            for placed in (
                np.array([t.state.box() for t in tracks]),
                np.array([t.boxes[-1] for t in tracks]),
            )
        ]
        return np.minimum(*cost)

    def _one_track_per_body(
        self,
        matches: dict[int, int],
        observations: Sequence[Observation],
        boxes: np.ndarray,
        colours: np.ndarray,
    ) -> dict[int, int]:
        """``matches`` (obs -> live track) with no two tracks on one body.

        Two followed poses slide onto one person when the other is hidden behind them, and the
        matching, which pairs as many as it can, would give both to two tracks. Where two
        matched observations are one body (:func:`same_body`), the track whose motion and
        colour fit that body best (least :func:`association_cost`, its other candidate costing
        inf if gated out) keeps it; the other goes unmatched and coasts, so that it can take its
        own person back when they are seen again.
        """
        cfg = self.config
        kept = dict(matches)
        pairs = sorted(kept)
        for a, b in itertools.combinations(pairs, 2):
            if a not in kept or b not in kept:
                continue
            if not same_body(observations[a], observations[b], cfg):
                continue
            ka, kb = kept[a], kept[b]
            cost = self._cost([self._live[ka], self._live[kb]], boxes[[a, b]], colours[[a, b]])
            # Each track's best fit to the body (either view of it); ties keep the older track.
            fit = cost.min(axis=1)
            loser = b if (fit[0], ka) <= (fit[1], kb) else a
            del kept[loser]
        return kept

    def _observe(self, track: _Track, frame: int, obs: Observation, occluded: bool) -> None:
        """Record ``obs`` as ``track``'s observation in ``frame`` and confirm it when due."""
        if track.boxes:  # a new track's state already is its first box
            track.state = self._kalman.update(track.state, obs.box)
        track.last_frame = frame
        track.hits += 1
        track.frames.append(frame)
        track.boxes.append(obs.box)
        track.scores.append(obs.score)
        track.all_colours.append(obs.colour)
        has_colour = obs.colour[:PART_BINS].sum() > 0 and obs.colour[PART_BINS:].sum() > 0
        if has_colour and not occluded:
            rate = self.config.colour_rate
            track.colour = (1.0 - rate) * track.colour + rate * obs.colour
            track.clean_colours.append(obs.colour)
        due = track.hits >= self.config.min_hits or track.first_frame == self._shot_start
        if track.track_id is None and due:
            track.track_id = self._next_id
            self._next_id += 1


def _summarise(track: _Track) -> TrackSummary:
    first, last = track.frames[0], track.frames[-1]
    boxes = np.full((last - first + 1, 4), np.nan)
    scores = np.full(last - first + 1, np.nan)
    index = np.array(track.frames) - first
    boxes[index] = np.array(track.boxes)
    scores[index] = np.array(track.scores)
    observed = box_to_cxcywh(np.array(track.boxes))
    colours = track.clean_colours or track.all_colours
    return TrackSummary(
        track_id=int(track.track_id),
        first_frame=first,
        last_frame=last,
        frames_observed=len(track.frames),
        mean_size=observed[:, 2:].mean(axis=0),
        mean_centre=observed[:, :2].mean(axis=0),
        colour=np.mean(colours, axis=0),
        boxes=boxes,
        scores=scores,
    )


# ---------------------------------------------------------------------------------------------
# Helpers and the identity-switch metric


def _check_box(name: str, box: np.ndarray) -> np.ndarray:
    box = np.asarray(box, dtype=np.float64)
    if box.shape != (4,) or not np.isfinite(box).all():
        raise ValueError(f"{name} must be (4,) finite x0, y0, x1, y1, got {box!r}")
    if not (box[2] > box[0] and box[3] > box[1]):
        raise ValueError(f"{name} must have x1 > x0 and y1 > y0, got {box.tolist()}")
    return box


def _check_colour(name: str, colour: np.ndarray) -> np.ndarray:
    colour = np.asarray(colour, dtype=np.float64)
    if colour.shape != (DESCRIPTOR_SIZE,) or not np.isfinite(colour).all():
        raise ValueError(
            f"{name} must be a ({DESCRIPTOR_SIZE},) finite colour descriptor from appearance(), "
            f"got shape {colour.shape}"
        )
    return colour


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(A, B) intersection over union of (A, 4) and (B, 4) boxes."""
    inter = intersections(a, b)
    return inter / (box_areas(a)[:, None] + box_areas(b)[None, :] - inter)


def same_body(a: Observation, b: Observation, config: TrackerConfig) -> bool:
    """Whether two observations of one frame are one body: boxes overlapping by more than
    ``config.same_body_iou`` and, where both have keypoints, keypoints apart by a median of
    less than ``config.same_body_gap`` of the mean box height (two people in a clinch overlap
    as much, but their joints do not coincide)."""
    return one_body(a.box, a.keypoints, b.box, b.keypoints, config)


def one_body(
    box_a: np.ndarray,
    keypoints_a: np.ndarray | None,
    box_b: np.ndarray,
    keypoints_b: np.ndarray | None,
    config: TrackerConfig,
) -> bool:
    """:func:`same_body` on (4,) boxes and (J, 2) keypoints (or None)."""
    box_a, box_b = np.asarray(box_a, np.float64), np.asarray(box_b, np.float64)
    if _iou(box_a[None], box_b[None])[0, 0] <= config.same_body_iou:
        return False
    if keypoints_a is None or keypoints_b is None or np.shape(keypoints_a) != np.shape(keypoints_b):
        return True
    height = (box_a[3] - box_a[1] + box_b[3] - box_b[1]) / 2
    gap = np.median(np.linalg.norm(np.subtract(keypoints_a, keypoints_b), axis=1))
    return bool(gap < config.same_body_gap * height)


def count_identity_switches(
    per_frame_pairs: Iterable[Iterable[tuple[Hashable, int | None]]],
) -> int:
    """Identity switches, as counted by the CLEAR MOT metrics (Bernardin & Stiefelhagen 2008).

    Args:
        per_frame_pairs: for each frame in order, the (truth id, track id) pairs of that frame;
            track id None means the person was not tracked in that frame.

    Returns:
        How many times a person was given a track id other than the one last given to them.
        Frames where a person is untracked neither count nor forget their last id.
    """
    last: dict[Hashable, int] = {}
    switches = 0
    for pairs in per_frame_pairs:
        for truth, track in pairs:
            if track is None:
                continue
            if truth in last and last[truth] != track:
                switches += 1
            last[truth] = track
    return switches
