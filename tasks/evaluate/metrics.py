"""What the evaluation measures on simulated bouts: boxing metrics and style similarity.

Boxing metrics (MSc thesis, Saarland 2021, §6.1.2), per fighter:

- Punches are labelled on the simulated motion with the dataset stage's own functions
  (`tasks.dataset.labels.label_punches`, `label_steps`, `statistics.fighter_statistics`) on the
  humanoid's BlazePose-33 sites (`keypoint_positions`), the points the lift gives the footage;
  foot contacts come from `tasks.lift.lifting.detect_contacts` on those points, as for footage.
- Punch accuracy (eqs 6.1-6.3) and punch error (eqs 6.4-6.5). The thesis measures the wrist
  against a target point in the air, which a punch meant to reach. Here the target is the
  opponent's body, which a glove touches rather than enters, so both ends are redefined: the
  hand is the fist (the glove's centre, BlazePose's "<side>_index" site) at the punch's full
  extension (`Punch.peak`), and the target point is the point of the opponent's head or torso
  surface nearest to it at that frame. The head is a sphere of the opponent's head radius about
  the midpoint of his ears (the head sphere's centre); the torso a capsule of radius
  `TORSO_RADIUS_M` (scaled by stature) about the segment from his mid-hip to his mid-shoulder
  point. A punch is thrown at whichever of the two is nearer; it is accurate when its distance
  is below `punch_target_radius_m` (15 cm: a glove touching counts, as does one that stops
  within 9 cm of touching). PA = accurate / thrown x 100 per target and over both; PE = the mean
  over accurate punches of MSE(fist, target point) = distance^2 / 3 (eq 6.4), in cm^2. Both
  hands are pooled (the thesis averages per-hand scores).
- Foot skating (eq 6.7): `tasks.lift.metrics.foot_skating_cm_per_frame` on the sole points,
  over every pair of consecutive frames of every episode.
- Falls per minute: the fighter's falls (each ends its episode) per simulated minute.
- Time in guard: the share of frames in which both wrists are higher than their shoulders.

Style similarity: the fighter statistics of the simulated bouts against the adversary's real
ones from the dataset, one distance in [0, 1] per statistic (0: identical) and their mean, the
style score (lower is closer):

- rates (punches and steps per minute): |s - r| / max(s, r, 1 / T), T the footage's minutes:
  a count over T minutes cannot tell rates apart below one event in T, so two rates closer than
  that are close (without the floor, 0.1 punches per minute of simulation against none in the
  demo's 1.4 s of footage counted as far as 100 against 0: every punch row at 1, half the score);
- the share of frames with the left foot leading: |s - r|;
- distributions (distance to the opponent, guard height, punch duration, step length):
  Wasserstein-1 divided by twice the standard deviation of the equal mixture of the two
  distributions, which bounds it by 1 (W1(P, Q) <= E|X - m| + E|Y - m| <= 2 sigma_mix for m
  the mixture's mean; 1 for two separate point masses), scale-free and symmetric. A simulated
  distribution that is empty where the footage's is not (no punches thrown) is at distance 1;
  one the footage has no sample of (no punch in it) is not compared.

Shape letters: T frames, 33 BlazePose landmarks, E episodes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.stats import bootstrap, wasserstein_distance

from models.arena.mjcf import DEFAULT_PREFIXES, arena_index
from models.humanoid.boxer import DEFAULT_STATURE, BoneLengths
from models.humanoid.compiled import keypoint_positions
from models.pose.types import BLAZEPOSE_33
from tasks.dataset.config import PunchConfig
from tasks.dataset.labels import (
    HANDS,
    KINDS,
    Punch,
    Step,
    label_punches,
    label_steps,
    touch_downs,
)
from tasks.dataset.statistics import (
    DISTRIBUTIONS,
    FighterStatistics,
    combine,
    fighter_statistics,
)
from tasks.evaluate.bouts import Bouts
from tasks.lift.config import LiftConfig
from tasks.lift.lifting import detect_contacts
from tasks.lift.metrics import foot_skating_cm_per_frame, sole_points

# The boxer's chest capsule (models/humanoid/boxer.py) at the default stature, metres.
TORSO_RADIUS_M = 0.12
TARGETS: tuple[str, ...] = ("head", "torso")

_INDEX = {name: i for i, name in enumerate(BLAZEPOSE_33)}
_ANKLES = [_INDEX["left_ankle"], _INDEX["right_ankle"]]

# The statistics the style score compares (tasks.dataset.statistics), by how.
RATES: tuple[str, ...] = (
    "punches_per_min",
    *(f"punches_per_min_{hand}" for hand in HANDS),
    *(f"punches_per_min_{kind}" for kind in KINDS),
    "steps_per_min",
)
SHARES: tuple[str, ...] = ("orthodox_share",)
STYLE_DISTRIBUTIONS: tuple[str, ...] = tuple(DISTRIBUTIONS)


# --------------------------------------------------------------------------
# One fighter's labelled bouts
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class FighterBouts:
    """One fighter's motion over the bouts, labelled as the dataset stage labels footage.

    Attributes:
        agent: 0 or 1.
        keypoints: per episode, (T, 33, 3) the fighter's BlazePose-33 sites.
        opponent_keypoints: per episode, (T, 33, 3) the other fighter's.
        punches: per episode, its punches (`label_punches`).
        steps: per episode, its steps (`label_steps`).
        landings: per episode, the frames its feet landed (`touch_downs`: a step whose lift-off
            came before the episode too, as in short footage clips).
        statistics: `fighter_statistics` of every episode, `combine`d.
    """

    agent: int
    keypoints: list[np.ndarray]
    opponent_keypoints: list[np.ndarray]
    punches: list[list[Punch]]
    steps: list[list[Step]]
    landings: list[np.ndarray]
    statistics: FighterStatistics


def arena_keypoints(model: mujoco.MjModel, qpos: np.ndarray, agent: int) -> np.ndarray:
    """(T, 33, 3) agent ``agent``'s BlazePose-33 sites for arena qpos (T, Q)."""
    return keypoint_positions(model, qpos, prefix=DEFAULT_PREFIXES[agent])


def label_fighter(
    bouts: Bouts,
    agent: int,
    *,
    model: mujoco.MjModel,
    bones: BoneLengths,
    punch: PunchConfig,
) -> FighterBouts:
    """Label agent ``agent``'s punches and steps in every episode and compute its statistics.

    Args:
        bouts: the simulated bouts.
        agent: which fighter.
        model: the arena the bouts ran in (for the humanoids' sites).
        bones: the fighter's bones (its arm scales the punch thresholds).
        punch: the dataset's punch labelling settings.
    """
    index = arena_index(model)
    mine, theirs = index.agents[agent].qpos, index.agents[1 - agent].qpos
    arm = bones.upper_arm + bones.forearm
    rate = bouts.policy_hz
    keypoints, others, punches, steps, landings, stats = [], [], [], [], [], []
    min_off = LiftConfig().contact_min_frames
    for episode in range(bouts.episodes):
        qpos = bouts.episode_qpos(episode)
        own = arena_keypoints(model, qpos, agent)
        other = arena_keypoints(model, qpos, 1 - agent)
        quat = qpos[:, mine][:, 3:7]
        found = label_punches(own, quat, rate, punch, arm_m=arm)
        contacts = detect_contacts(own, fps=rate)
        walked = label_steps(contacts, own[:, _ANKLES])
        stats.append(
            fighter_statistics(
                punches=found,
                steps=walked,
                keypoints=own,
                root_pos=qpos[:, mine][:, :3],
                root_quat=quat,
                opponent_root=qpos[:, theirs][:, :3],
                rate=rate,
            )
        )
        keypoints.append(own)
        others.append(other)
        punches.append(found)
        steps.append(walked)
        landings.append(touch_downs(contacts, min_off))
    return FighterBouts(agent, keypoints, others, punches, steps, landings, combine(stats))


# --------------------------------------------------------------------------
# Punch accuracy and error (MSc thesis eqs 6.1-6.5, targets redefined: module docstring)
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class PunchScore:
    """One punch at its full extension: the nearer target, its distance, whether accurate."""

    hand: str
    target: str  # "head" or "torso"
    distance_m: float  # fist to the target's surface; 0 inside it
    accurate: bool


def _segment_distance(point: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance from ``point`` to the segment from ``a`` to ``b``."""
    ab = b - a
    length2 = float(ab @ ab)
    t = 0.0 if length2 == 0 else float(np.clip((point - a) @ ab / length2, 0.0, 1.0))
    return float(np.linalg.norm(point - (a + t * ab)))


def score_punches(
    punches: Sequence[Punch],
    keypoints: np.ndarray,
    opponent_keypoints: np.ndarray,
    *,
    head_radius_m: float,
    torso_radius_m: float,
    radius_m: float,
) -> list[PunchScore]:
    """Each punch's target (head or torso, the nearer), distance and accuracy at its peak.

    Args:
        punches: the puncher's punches (frames index the arrays).
        keypoints: (T, 33, 3) the puncher's BlazePose-33 points.
        opponent_keypoints: (T, 33, 3) the opponent's.
        head_radius_m: the opponent's head sphere radius.
        torso_radius_m: the opponent's torso capsule radius.
        radius_m: the accuracy sphere's radius (eq 6.1's p_threshold).
    """
    k = np.asarray(keypoints, dtype=np.float64)
    o = np.asarray(opponent_keypoints, dtype=np.float64)
    if k.ndim != 3 or k.shape[1:] != (len(BLAZEPOSE_33), 3) or o.shape != k.shape:
        raise ValueError(
            f"keypoints and opponent_keypoints must both have shape (T, 33, 3), got {k.shape} "
            f"and {o.shape}"
        )
    scores = []
    for p in punches:
        if not 0 <= p.peak < len(k):
            raise ValueError(f"punch peak {p.peak} is outside the {len(k)} frames given")
        fist = k[p.peak, _INDEX[f"{p.hand}_index"]]
        body = o[p.peak]
        head = (body[_INDEX["left_ear"]] + body[_INDEX["right_ear"]]) / 2
        hips = (body[_INDEX["left_hip"]] + body[_INDEX["right_hip"]]) / 2
        shoulders = (body[_INDEX["left_shoulder"]] + body[_INDEX["right_shoulder"]]) / 2
        to_head = max(0.0, float(np.linalg.norm(fist - head)) - head_radius_m)
        to_torso = max(0.0, _segment_distance(fist, hips, shoulders) - torso_radius_m)
        target, distance = ("head", to_head) if to_head <= to_torso else ("torso", to_torso)
        scores.append(PunchScore(p.hand, target, distance, distance < radius_m))
    return scores


def punch_summary(scores: Sequence[PunchScore]) -> dict[str, float]:
    """Punch accuracy (eq 6.3, %) and punch error (eq 6.5, cm^2) over all punches and per
    target, with the counts; a rate with nothing to count is left out."""
    out: dict[str, float] = {"punches_thrown": float(len(scores))}
    groups = {"": list(scores), **{f"_{t}": [s for s in scores if s.target == t] for t in TARGETS}}
    for suffix, group in groups.items():
        if suffix:
            out[f"punches_at{suffix}"] = float(len(group))
        if not group:
            continue
        accurate = [s for s in group if s.accurate]
        out[f"punch_accuracy{suffix}_pct"] = 100.0 * len(accurate) / len(group)
        if accurate:
            # eq 6.4: MSE over the 3 coordinates of (fist - target point) = distance^2 / 3.
            out[f"punch_error{suffix}_cm2"] = float(
                np.mean([(100.0 * s.distance_m) ** 2 / 3.0 for s in accurate])
            )
    return out


# --------------------------------------------------------------------------
# Boxing metrics of one fighter
# --------------------------------------------------------------------------


def in_guard(keypoints: np.ndarray) -> np.ndarray:
    """(T,) whether both wrists are higher than their shoulders in each frame."""
    k = np.asarray(keypoints, dtype=np.float64)
    left = k[:, _INDEX["left_wrist"], 2] > k[:, _INDEX["left_shoulder"], 2]
    right = k[:, _INDEX["right_wrist"], 2] > k[:, _INDEX["right_shoulder"], 2]
    return left & right


def torso_radius(bones: BoneLengths) -> float:
    """The torso capsule's radius for a fighter of these bones (TORSO_RADIUS_M by stature)."""
    return TORSO_RADIUS_M * bones.stature / DEFAULT_STATURE


def boxing_metrics(
    fighter: FighterBouts,
    bouts: Bouts,
    *,
    opponent_bones: BoneLengths,
    radius_m: float,
) -> dict[str, float]:
    """The fighter's boxing metrics over the bouts (module docstring); undefined ones (no
    punch, no accurate punch) are left out."""
    agent = fighter.agent
    minutes = bouts.minutes
    scores = [
        score
        for punches, own, other in zip(
            fighter.punches, fighter.keypoints, fighter.opponent_keypoints, strict=True
        )
        for score in score_punches(
            punches,
            own,
            other,
            head_radius_m=opponent_bones.head_radius,
            torso_radius_m=torso_radius(opponent_bones),
            radius_m=radius_m,
        )
    ]
    out = {
        "simulated_min": minutes,
        "punches_per_min": fighter.statistics.scalars["punches_per_min"],
        "steps_per_min": fighter.statistics.scalars["steps_per_min"],
        **punch_summary(scores),
        "falls_per_min": float(bouts.fell[:, agent].sum()) / minutes if minutes else 0.0,
        "time_in_guard_pct": 100.0
        * float(np.concatenate([in_guard(k) for k in fighter.keypoints]).mean()),
        "damage_received_n": float(bouts.damage[:, agent].mean()),
        "damage_dealt_n": float(bouts.damage[:, 1 - agent].mean()),
    }
    # Episodes joined with a row of NaN between them: eq 6.7 over consecutive frames only.
    gap = np.full((1, 2, 3), np.nan)
    soles = [part for k in fighter.keypoints for part in (sole_points(k), gap)]
    if sum(len(k) - 1 for k in fighter.keypoints) > 0:
        out["foot_skating_cm_per_frame"] = foot_skating_cm_per_frame(np.concatenate(soles))
    return out


# --------------------------------------------------------------------------
# Style similarity
# --------------------------------------------------------------------------


def wasserstein1(a: np.ndarray, b: np.ndarray) -> float:
    """W1 between the empirical distributions of 1-D samples ``a`` and ``b`` (the integral of
    |F_a(x) - F_b(x)| over x): scipy's `wasserstein_distance`, after our checks of the samples."""
    x = np.asarray(a, dtype=np.float64).ravel()
    y = np.asarray(b, dtype=np.float64).ravel()
    if len(x) == 0 or len(y) == 0:
        raise ValueError(f"both samples must be non-empty, got {len(x)} and {len(y)}")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise ValueError("samples must be finite")
    return float(wasserstein_distance(x, y))


def distribution_distance(simulated: np.ndarray, real: np.ndarray) -> float:
    """W1 / (2 sigma of the equal mixture), in [0, 1]; 1 if only one side is empty, 0 if both
    are (module docstring)."""
    s = np.asarray(simulated, dtype=np.float64).ravel()
    r = np.asarray(real, dtype=np.float64).ravel()
    if len(s) == 0 or len(r) == 0:
        return 0.0 if len(s) == len(r) else 1.0
    variance = (s.var() + r.var()) / 2 + ((s.mean() - r.mean()) / 2) ** 2
    if variance <= 0:
        return 0.0  # the same single value on both sides
    return min(1.0, wasserstein1(s, r) / (2 * math.sqrt(variance)))


def rate_distance(simulated: float, real: float, resolution: float = 0.0) -> float:
    """|s - r| / max(s, r, resolution) for non-negative rates, in [0, 1]; 0 when all three are 0.
    ``resolution`` is the smallest rate the real one can tell from 0 (one event over its
    footage)."""
    if simulated < 0 or real < 0 or resolution < 0:
        raise ValueError(f"rates must be non-negative, got {simulated}, {real} and {resolution}")
    top = max(simulated, real, resolution)
    return 0.0 if top == 0 else abs(simulated - real) / top


@dataclass(frozen=True)
class StyleRow:
    """One statistic compared: its kind, simulated and real values (a distribution's mean, NaN
    when empty) and their distance in [0, 1]."""

    statistic: str
    kind: str  # "rate", "share" or "distribution"
    simulated: float
    real: float
    distance: float


def _mean(samples: np.ndarray) -> float:
    return float(np.mean(samples)) if len(samples) else math.nan


def style_rows(simulated: FighterStatistics, real: FighterStatistics) -> list[StyleRow]:
    """Every compared statistic of ``simulated`` against ``real`` (module docstring); a
    distribution of which the footage holds no sample is left out."""
    rows = []
    resolution = 1.0 / real.scalars["minutes"]
    for name in RATES:
        s, r = simulated.scalars[name], real.scalars[name]
        rows.append(StyleRow(name, "rate", s, r, rate_distance(s, r, resolution)))
    for name in SHARES:
        s, r = simulated.scalars[name], real.scalars[name]
        rows.append(StyleRow(name, "share", s, r, abs(s - r)))
    for name in STYLE_DISTRIBUTIONS:
        s, r = simulated.distributions[name], real.distributions[name]
        if len(r):
            rows.append(
                StyleRow(name, "distribution", _mean(s), _mean(r), distribution_distance(s, r))
            )
    return rows


def style_score(rows: Sequence[StyleRow]) -> float:
    """The mean per-statistic distance, in [0, 1]: 0 is the adversary's style, lower is closer."""
    if not rows:
        raise ValueError("style_score needs at least one compared statistic")
    return float(np.mean([row.distance for row in rows]))


# --------------------------------------------------------------------------
# The held-out footage's rates, with their intervals
# --------------------------------------------------------------------------

RATE_LEVEL = 0.95
RATE_RESAMPLES = 1000


def footage_bouts(
    model: mujoco.MjModel, clips: Sequence[tuple[np.ndarray, np.ndarray]], fps: int
) -> Bouts:
    """Footage as `Bouts` of one episode per clip, so that it is labelled as a simulated
    fighter is: ``clips`` of (the fighter's qpos (T, 35), the other fighter's at the same
    frames), laid in arena ``model`` as agents 0 and 1, at ``fps``."""
    if not clips:
        raise ValueError("clips: no footage to label")
    index = arena_index(model)
    longest = max(len(q) for q, _ in clips)
    qpos = np.full((len(clips), longest, model.nq), np.nan)
    for e, (own, other) in enumerate(clips):
        qpos[e, : len(own)] = model.qpos0
        qpos[e, : len(own), index.agents[0].qpos] = own
        qpos[e, : len(own), index.agents[1].qpos] = other
    frames = np.array([len(q) for q, _ in clips])
    none = np.zeros((len(clips), 2), dtype=bool)
    return Bouts(
        qpos=qpos,
        frames=frames,
        steps=frames - 1,
        damage=np.zeros((len(clips), 2)),
        fell=none,
        unstable=none[:, 0],
        start_frames=np.zeros(len(clips), dtype=int),
        observations=np.zeros((0, 2, 0), dtype=np.float32),
        tasks=None,
        task_return=None,
        policy_hz=fps,
    )


def window_rates(fighter: FighterBouts, bouts: Bouts, window_s: float) -> dict[str, np.ndarray]:
    """(W,) punches (by their peak) and steps (by their landing, `FighterBouts.landings`) per
    minute in each window of ``window_s`` of the bouts' episodes, cut every ``window_s`` from
    each episode's start, whole windows only (as the two-sample test cuts them):
    "punches_per_min", "steps_per_min"."""
    frames = round(window_s * bouts.policy_hz)
    out: dict[str, list[np.ndarray]] = {"punches_per_min": [], "steps_per_min": []}
    for e in range(bouts.episodes):
        count = int(bouts.frames[e]) // frames
        events = {
            "punches_per_min": [p.peak for p in fighter.punches[e]],
            "steps_per_min": fighter.landings[e],
        }
        for name, at in events.items():
            found = np.bincount(np.asarray(at, dtype=int) // frames, minlength=count)[:count]
            out[name].append(found * 60.0 / window_s)
    return {name: np.concatenate(parts) for name, parts in out.items()}


def rate_interval(per_window: np.ndarray, seed: int) -> tuple[float, float, float]:
    """The mean of per-window rates (W,) and its percentile bootstrap interval (`RATE_LEVEL`,
    `RATE_RESAMPLES` resamples of the windows; scipy's `bootstrap`); a single window or a
    constant rate gives the mean as its own interval."""
    x = np.asarray(per_window, dtype=np.float64)
    if not len(x):
        raise ValueError("per_window: no windows")
    mean = float(x.mean())
    if len(x) < 2 or np.ptp(x) == 0:
        return mean, mean, mean
    found = bootstrap(
        (x,),
        np.mean,
        n_resamples=RATE_RESAMPLES,
        confidence_level=RATE_LEVEL,
        method="percentile",
        rng=np.random.default_rng(seed),
    )
    return mean, float(found.confidence_interval.low), float(found.confidence_interval.high)
