"""A partner-aware motion matcher: which frame of a fighter's own footage to play next.

Motion matching (Clavet 2016; DReCon, Bergamin et al. 2019; Holden et al. 2020) keeps a feature
vector per frame of a motion database and, every few steps, plays on from the frame whose
features are nearest to a query made of the character's current state. Here the database is one
fighter's clips with the other fighter of the footage at the same frames, and a frame's features
are (`FEATURE_GROUPS`, all in the fighter's heading frame, so a frame matches wherever and
whichever way it was filmed):

- its own body: feet and hands relative to the pelvis, their velocities, the pelvis's velocity
  and yaw rate;
- where its pelvis goes over the next second, and which way it faces then (`MatchConfig.future_s`);
- the other fighter: the pelvis distance on the floor, its bearing, its approach speed (the rate
  at which the distance shrinks) and where its hands are.

A query is the same features of a simulated fighter and its partner; its future part is the
future of the frame the fighter plays now (the motion's own intention: a matcher without
another input prefers to play on). So what the adversary did when the other fighter stood where
the partner stands now is what the search finds.

Each feature is standardised over the database (its mean and standard deviation) and a group's
features are scaled by the group's weight over the square root of its size, so that a weight is
the group's share of the distance whatever its width (`MatchWeights`). The search is a KD-tree
(scipy's cKDTree) over the weighted features, with a brute force beside it (`nearest_brute`) that
the tests hold it to. A frame is a candidate when a whole future lies in its clip
(`MotionDatabase.candidates`); the frames near the one being played are left out of a search
(`MatchConfig.skip_frames`), so that a match is a change, not a step on.

Shape letters: F frames of the database, B queries, D weighted features.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from models.humanoid.kinematics import BODY_NAMES, heading_frame_of_matrix
from models.humanoid.observations import BodyState, in_heading
from models.tracking.clips import ClipLibrary, ReferenceClip, clip_library

FEET = [BODY_NAMES.index("left_foot"), BODY_NAMES.index("right_foot")]
HANDS = [BODY_NAMES.index("left_hand"), BODY_NAMES.index("right_hand")]

# The feature groups, in the vector's order (their widths: `MotionDatabase.slices`).
FEATURE_GROUPS = (
    "feet",
    "hands",
    "limb_velocity",
    "pelvis_velocity",
    "yaw_rate",
    "future_position",
    "future_facing",
    "partner_distance",
    "partner_bearing",
    "partner_approach",
    "partner_hands",
)


@dataclass(frozen=True)
class MatchWeights:
    """Each feature group's share of the distance (module docstring); 0 leaves it out."""

    feet: float = 1.0
    hands: float = 1.0
    limb_velocity: float = 1.0
    pelvis_velocity: float = 1.0
    yaw_rate: float = 0.5
    future_position: float = 1.0
    future_facing: float = 1.0
    partner_distance: float = 2.0
    partner_bearing: float = 1.0
    partner_approach: float = 1.0
    partner_hands: float = 1.0

    def __post_init__(self) -> None:
        bad = [g for g in FEATURE_GROUPS if not getattr(self, g) >= 0.0]
        if bad:
            raise ValueError(f"match weights must be >= 0, got {', '.join(bad)}")


@dataclass(frozen=True)
class MatchConfig:
    """The matcher's settings.

    Attributes:
        weights: the feature groups' weights.
        future_s: the times ahead (s) at which a frame's future pelvis is taken (DReCon and
            Holden et al. take three over a second).
        skip_frames: a search leaves out the frames of the played clip within this many frames
            of the one being played.
        search_every: policy steps between searches (DReCon searches every 0.2 s, game motion
            matchers every 0.1 s: 3 steps at 30 Hz).
        blend_steps: policy steps over which a new match's frames are cross-faded in.
        anchor_m: the played motion is moved back onto the simulated pelvis when it strays
            further than this on the floor (DReCon keeps its kinematic root within 0.5 m).
        ease_steps: policy steps over which an episode's first match is faded in from the
            body as it stands (held still), so that a fighter at rest is not asked for the
            footage's full speed at once; 0: none.
    """

    weights: MatchWeights = field(default_factory=MatchWeights)
    future_s: tuple[float, ...] = (1 / 3, 2 / 3, 1.0)
    skip_frames: int = 10
    search_every: int = 3
    blend_steps: int = 6
    anchor_m: float = 0.5
    ease_steps: int = 30

    def __post_init__(self) -> None:
        if not self.future_s or any(not t > 0 for t in self.future_s):
            raise ValueError(f"future_s must be times > 0, got {self.future_s}")
        if self.skip_frames < 0 or self.blend_steps < 0 or self.ease_steps < 0:
            raise ValueError(
                f"skip_frames, blend_steps and ease_steps must be >= 0, got {self.skip_frames}, "
                f"{self.blend_steps}, {self.ease_steps}"
            )
        if self.search_every < 1 or not self.anchor_m > 0:
            raise ValueError(
                f"search_every must be >= 1 and anchor_m > 0, got {self.search_every}, "
                f"{self.anchor_m}"
            )

    def as_dict(self) -> dict:
        """The settings as JSON-ready values (an opponent folder's manifest keeps them)."""
        return {
            "weights": {g: getattr(self.weights, g) for g in FEATURE_GROUPS},
            "future_s": list(self.future_s),
            "skip_frames": self.skip_frames,
            "search_every": self.search_every,
            "blend_steps": self.blend_steps,
            "anchor_m": self.anchor_m,
            "ease_steps": self.ease_steps,
        }

    @classmethod
    def from_dict(cls, values: dict) -> MatchConfig:
        """`as_dict`'s values back; TypeError or ValueError for what is not settings."""
        given = dict(values)
        weights = MatchWeights(**given.pop("weights", {}))
        future = tuple(float(t) for t in given.pop("future_s", cls.future_s))
        return cls(weights=weights, future_s=future, **given)


def body_features(state: BodyState) -> dict[str, np.ndarray]:
    """The own-body groups of `FEATURE_GROUPS` for states (...): feet (..., 6), hands (..., 6),
    limb_velocity (..., 12), pelvis_velocity (..., 3), yaw_rate (..., 1)."""
    heading = heading_frame_of_matrix(state.rot[..., 0, :, :])
    root = state.pos[..., 0:1, :]
    lead = state.pos.shape[:-2]
    limbs = FEET + HANDS
    relative = in_heading(heading, state.pos[..., limbs, :] - root)
    velocity = in_heading(heading, state.lin_vel[..., [*limbs, 0], :])
    return {
        "feet": relative[..., :2, :].reshape(*lead, 6),
        "hands": relative[..., 2:, :].reshape(*lead, 6),
        "limb_velocity": velocity[..., :4, :].reshape(*lead, 12),
        "pelvis_velocity": velocity[..., 4, :],
        "yaw_rate": state.ang_vel[..., 0, 2:3],
    }


def partner_features(state: BodyState, partner: BodyState) -> dict[str, np.ndarray]:
    """The partner groups of `FEATURE_GROUPS` for a fighter's states (...) and its partner's
    at the same instants: partner_distance (..., 1, m on the floor), partner_bearing (..., 2, the
    unit direction to the partner in the heading frame), partner_approach (..., 1, m/s at which
    the distance shrinks), partner_hands (..., 6)."""
    heading = heading_frame_of_matrix(state.rot[..., 0, :, :])
    lead = state.pos.shape[:-2]
    gap = partner.pos[..., 0, :2] - state.pos[..., 0, :2]
    distance = np.linalg.norm(gap, axis=-1, keepdims=True)
    towards = gap / np.maximum(distance, 1e-9)
    closing = partner.lin_vel[..., 0, :2] - state.lin_vel[..., 0, :2]
    hands = partner.pos[..., HANDS, :] - state.pos[..., 0:1, :]
    bearing = in_heading(heading, np.concatenate([towards, np.zeros((*lead, 1))], -1)[..., None, :])
    return {
        "partner_distance": distance,
        "partner_bearing": bearing[..., 0, :2],
        "partner_approach": -np.sum(closing * towards, axis=-1, keepdims=True),
        "partner_hands": in_heading(heading, hands).reshape(*lead, 6),
    }


def future_features(state: BodyState, ahead: np.ndarray) -> dict[str, np.ndarray]:
    """future_position (..., 2K) and future_facing (..., 2K): where the pelvis of states
    ``ahead`` (..., K) lies on the floor, and where its x axis points, in the heading frame of
    ``state`` (...) and from its pelvis."""
    heading = heading_frame_of_matrix(state.rot[..., 0, :, :])
    lead = state.pos.shape[:-2]
    k = ahead.pos.shape[-3]
    offset = ahead.pos[..., 0, :] - state.pos[..., None, 0, :]
    offset[..., 2] = 0.0
    facing = ahead.rot[..., 0, :, 0].copy()
    facing[..., 2] = 0.0
    facing /= np.maximum(np.linalg.norm(facing, axis=-1, keepdims=True), 1e-9)
    return {
        "future_position": in_heading(heading, offset)[..., :2].reshape(*lead, 2 * k),
        "future_facing": in_heading(heading, facing)[..., :2].reshape(*lead, 2 * k),
    }


def _joined(groups: dict[str, np.ndarray]) -> np.ndarray:
    return np.concatenate([groups[g] for g in FEATURE_GROUPS], axis=-1)


@dataclass(frozen=True, eq=False)
class MotionDatabase:
    """One fighter's clips, each frame's features and the weighted search space.

    Attributes:
        library: the fighter's clips end to end (F frames), as the tracker indexes them.
        partner: (F,) body states of the other fighter at the same frames.
        features: (F, D) each frame's raw features, `FEATURE_GROUPS` in order (a frame without
            a whole future in its clip has its future clamped to the clip's last frame).
        slices: where each group of `FEATURE_GROUPS` lies in a feature vector.
        mean, scale: (D,) the features' weighting: weighted = (features - mean) * scale.
        candidates: the flat indices of the frames a search may return (a whole future ahead).
        config: the matcher's settings.
    """

    library: ClipLibrary
    partner: BodyState
    features: np.ndarray
    slices: dict[str, slice]
    mean: np.ndarray
    scale: np.ndarray
    candidates: np.ndarray
    config: MatchConfig
    _tree: cKDTree = field(repr=False)

    @property
    def future_steps(self) -> np.ndarray:
        """(K,) the future times in frames."""
        return future_frames(self.config, self.library.fps)

    def weighted(self, features: np.ndarray) -> np.ndarray:
        """(..., D) raw features standardised and weighted, as the search compares them."""
        return (features - self.mean) * self.scale

    def query(
        self, state: BodyState, partner: BodyState, future_of: np.ndarray | None
    ) -> np.ndarray:
        """(B, D) raw query features of fighters ``state`` (B,) with partners ``partner`` (B,);
        their future is that of database frames ``future_of`` (B,), the frames they play, or
        with None the standing one (no move, facing ahead: a fighter playing nothing yet)."""
        groups = {**body_features(state), **partner_features(state, partner)}
        k, count = len(self.config.future_s), len(state.pos)
        if future_of is None:
            groups["future_position"] = np.zeros((count, 2 * k))
            groups["future_facing"] = np.tile([1.0, 0.0], (count, k))
        else:
            ahead = self.features[np.asarray(future_of, dtype=int)]
            for name in ("future_position", "future_facing"):
                groups[name] = ahead[..., self.slices[name]]
        return _joined(groups)

    def distance(self, query: np.ndarray, frames: np.ndarray) -> np.ndarray:
        """(B,) the weighted distance from each raw query (B, D) to database frame ``frames``
        (B,)."""
        return np.linalg.norm(self.weighted(query) - self.weighted(self.features[frames]), axis=-1)

    def _allowed(self, found: np.ndarray, playing: np.ndarray) -> np.ndarray:
        """Whether each of ``found`` (B, k) may be returned for queries playing ``playing``
        (B,; -1 for none): not within `MatchConfig.skip_frames` of the played frame in its
        clip."""
        clip_found, _ = self.library.locate(found)
        clip_playing, _ = self.library.locate(np.maximum(playing, 0))
        near = np.abs(found - playing[:, None]) <= self.config.skip_frames
        same = (clip_found == clip_playing[:, None]) & (playing[:, None] >= 0)
        return ~(near & same)

    def nearest(self, query: np.ndarray, playing: np.ndarray) -> np.ndarray:
        """(B,) the candidate frame nearest to each raw query (B, D) other than those near the
        frame it plays (``playing`` (B,); -1 for none), by the KD-tree. Where every candidate
        is near it (footage of a second or two: every candidate is in the played clip), the
        nearest candidate of all: the only motion there is."""
        points = self.weighted(query)
        playing = np.asarray(playing, dtype=int)
        # At most 2 skip + 1 candidates are near the played frame, so the nearest 2 skip + 2
        # hold an allowed one unless the candidates are that few.
        k = min(2 * self.config.skip_frames + 2, len(self.candidates))
        _, found = self._tree.query(points, k=k)
        found = self.candidates[np.asarray(found).reshape(len(points), k)]
        allowed = self._allowed(found, playing)
        first = np.where(allowed.any(axis=1), np.argmax(allowed, axis=1), 0)
        return found[np.arange(len(points)), first]

    def nearest_brute(self, query: np.ndarray, playing: np.ndarray) -> np.ndarray:
        """`nearest` by comparing each query with every candidate."""
        points = self.weighted(query)
        playing = np.asarray(playing, dtype=int)
        space = self.weighted(self.features[self.candidates])
        distance = cdist(points, space, "sqeuclidean")
        found = np.broadcast_to(self.candidates, distance.shape)
        allowed = self._allowed(found, playing)
        distance = np.where(allowed | ~allowed.any(axis=1, keepdims=True), distance, np.inf)
        return self.candidates[np.argmin(distance, axis=1)]


def future_frames(config: MatchConfig, fps: float) -> np.ndarray:
    """(K,) the matcher's future times (`MatchConfig.future_s`) in frames at ``fps``."""
    return np.rint(np.asarray(config.future_s) * fps).astype(int)


def motion_database(
    clips: Sequence[ReferenceClip],
    partners: Sequence[ReferenceClip],
    *,
    fps: float,
    config: MatchConfig | None = None,
) -> MotionDatabase:
    """The database of a fighter's ``clips`` with the other fighter's ``partners`` (the same
    frames, clip by clip), at ``fps``.

    Raises:
        ValueError: a partner clip of another length than its clip, or no clip long enough to
            hold a whole future (`MatchConfig.future_s`) after a frame.
    """
    config = config or MatchConfig()
    for clip, partner in zip(clips, partners, strict=True):
        if partner.num_frames != clip.num_frames:
            raise ValueError(
                f"clip {clip.name!r}: {clip.num_frames} frames, its partner's {partner.num_frames}"
            )
    library = clip_library(clips, fps=fps)
    states = library.clip.states
    partner = clip_library(partners, fps=fps).clip.states
    steps = future_frames(config, fps)
    flat = np.arange(len(library.clip.qpos))
    clip_of, _ = library.locate(flat)
    last = library.last[clip_of]
    ahead = np.minimum(flat[:, None] + steps, last[:, None])
    groups = {
        **body_features(states),
        **partner_features(states, partner),
        **future_features(states, states[ahead]),
    }
    features = _joined(groups)
    widths = np.cumsum([0] + [groups[g].shape[-1] for g in FEATURE_GROUPS])
    slices = {
        g: slice(a, b) for g, a, b in zip(FEATURE_GROUPS, widths[:-1], widths[1:], strict=True)
    }
    candidates = flat[flat + steps.max() <= last]
    if not candidates.size:
        raise ValueError(
            f"no clip is longer than the matcher's future ({max(config.future_s):g} s): "
            "nothing to match"
        )
    mean = features[candidates].mean(axis=0)
    std = features[candidates].std(axis=0)
    scale = np.zeros(features.shape[1])
    for name, part in slices.items():
        width = part.stop - part.start
        # A feature constant over the database (a clip filmed still) compares as 0, not 1/0.
        spread = np.where(std[part] > 1e-6, std[part], np.inf)
        scale[part] = getattr(config.weights, name) / np.sqrt(width) / spread
    tree = cKDTree((features[candidates] - mean) * scale)
    return MotionDatabase(library, partner, features, slices, mean, scale, candidates, config, tree)
