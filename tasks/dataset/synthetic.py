"""A synthetic adversary: DeepMimic's clips on the sample's two bodies, as a regular dataset.

Training judged on the lifted footage cannot tell the method's faults from the lift's noise
(issue 32). This makes a dataset whose motion is clean mocap: DeepMimic's walk and punch and
the walker's straight walk and four turns (`CLIP_NAMES`, `tasks.deepmimic`), retargeted onto
two bodies (by default the bones the lift measured for the bundled sample's fighters). It is
recorded as the pipeline records footage: a lift output (``lift_motion``, ``lift_bones``) of a
pseudo video ``synthetic-…``, a dataset output made from it by the dataset stage's own
`tasks.dataset.stage.build_dataset` (clips, transitions, punches, steps, statistics), and a
dataset joining that one output, so that ``ringside train --dataset KEY`` and evaluation read it
as they read any other.

The performance (`performance`): ``rounds`` rounds; each round plays every clip once, in an
order drawn from ``seed``. Each play is an *exchange*, a shot of its own (as after a camera
cut): the adversary performs the clip as retargeted, and the opponent performs the same clip on
its own body, time-reversed, placed by one rigid move on the floor (`place_opponent`) that best
keeps it ``distance_m`` from the adversary with both facing each other. Reversed, a walk
retreats as the adversary's walk advances, so the range holds, while each fighter's motion stays
mocap, without a synthetic frame: on the sample's bodies at 1.2 m the pelvises stay 0.76-1.42 m
apart (mean 1.19; the walks and turns within 1.16-1.28 m, the punch, which steps in 1.2 m and
turns 110 degrees, the rest) and each fighter's heading is 16 degrees off the other on average
(65 at worst, in the walker's 99-degree turn). A continuous chain of the clips was the other
way, and was left: with no sideways or backward clip, a partner cannot stay in front of a
fighter through a turn without sliding its feet, and every cross-fade would be motion no one
performed. The metrics say how well the placement holds (``distance_*_m``,
``facing_error_*_deg``). The opponent's reversed punch is labelled a right uppercut.

The split (`split_windows`): each exchange is cut into windows of ``window_s`` (1 s; its last
window takes the remainder, so the walker's 38 frames are one window of 1.27 s and the punch's
65 two, of 30 and 35 steps), and ``held_out_fraction`` (0.3) of the windows, drawn from
``seed``, are held out as the validation split, stratified by clip and window so that every
movement is in both splits. Runs of one exchange's consecutive windows in the same split are
the clips (`pieces`). The dataset stage itself splits by time (the last
``dataset.validation_fraction`` of a video), so it is run with that fraction 0 and its clips'
split is then set by their window (`split_by_windows`); labels and statistics do not depend on
it.

Held-out windows are other plays of the same few seconds of mocap (the seven clips are 9.8 s),
so they measure how well a policy reproduces these movements, not whether it generalises to
unseen ones.

Shape letters: T frames of a clip, N steps of the performance.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import duckdb
import numpy as np

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.kinematics import heading_yaw, wrap_angle
from models.humanoid.motion import RATE, FighterMotion, fighter_distance
from models.settings import setting
from storage.keys import code_version, digest
from tasks.dataset.config import DatasetConfig
from tasks.dataset.store import ClipRow
from tasks.errors import BadInput
from tasks.lift.store import bone_rows, load_bones, newest_lift
from tasks.roles import ROLES
from tasks.runner import StageOutput, StageSpec

# MuJoCo, `tasks.deepmimic` (scipy's rotations), scipy.optimize and the lift's contacts (torch)
# are imported by the functions that use them: the command line's parser reads
# `SyntheticConfig` from here on every command, and they took 0.5 s.

# The clips the adversary performs (`tasks.deepmimic.clip_path` names: its walk and punch, and
# the walker's clips).
CLIP_NAMES: tuple[str, ...] = (
    "walk",
    "punch",
    "walker_forward",
    "walker_turn_left0",
    "walker_turn_left1",
    "walker_turn_right0",
    "walker_turn_right1",
)
PREFIX = "synthetic-"  # the pseudo video id's
LIFT = "lift"  # the stage whose tables hold the motion (`tasks.lift.stage.STAGE`)
# How much a facing error of 1 rad costs in the placement, against a distance error in metres:
# 1 rad off is as bad as 0.5 m off.
_FACING_WEIGHT = 0.25


@dataclass(frozen=True)
class SyntheticConfig:
    """How the synthetic adversary's performance is made and split."""

    rounds: int = setting(
        6,
        "How many times the adversary performs every clip, each round in its own order: 6 "
        "rounds of the 7 clips are 59 s, 48 windows.",
    )
    window_s: float = setting(
        1.0,
        "Length of the windows split between train and held out (s); an exchange's last window "
        "takes its remainder.",
    )
    held_out_fraction: float = setting(
        0.3,
        "Share of the windows held out as the validation split (drawn from the seed, stratified "
        "by clip and window).",
    )
    distance_m: float = setting(
        1.2,
        "Pelvis-to-pelvis distance at which the opponent is placed facing the adversary (the "
        "training arena's separation).",
    )
    seed: int = setting(0, "Seeds the order of the clips in each round and the split.")

    def __post_init__(self) -> None:
        if isinstance(self.rounds, bool) or not (isinstance(self.rounds, int) and self.rounds >= 1):
            raise ValueError(f"synthetic rounds must be a whole number >= 1, got {self.rounds!r}")
        if not (math.isfinite(self.window_s) and self.window_s * RATE >= 2):
            raise ValueError(f"synthetic window_s must be at least 2 steps, got {self.window_s!r}")
        if not 0.0 <= self.held_out_fraction < 1.0:
            raise ValueError(
                f"synthetic held_out_fraction must be in [0, 1), got {self.held_out_fraction!r}"
            )
        if not (math.isfinite(self.distance_m) and self.distance_m > 0):
            raise ValueError(f"synthetic distance_m must be positive, got {self.distance_m!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int):
            raise ValueError(f"synthetic seed must be a whole number, got {self.seed!r}")

    @property
    def window_steps(self) -> int:
        return round(self.window_s * RATE)


def synthetic_code() -> str:
    return code_version("tasks.dataset.synthetic", "tasks.deepmimic", "models.humanoid")


# --------------------------------------------------------------------------------------------
# Inputs: the clips and the bodies


def clip_files(assets: Path) -> dict[str, Path]:
    """Each of `CLIP_NAMES`' file under ``assets``.

    Raises:
        BadInput: naming the first clip missing, and the command that pulls them.
    """
    from tasks import deepmimic

    files = {name: deepmimic.clip_path(assets, name) for name in CLIP_NAMES}
    for path in files.values():
        if not path.is_file():
            raise BadInput(
                str(path),
                "missing: the synthetic adversary needs DeepMimic's clips, dev assets that "
                "`ringside assets pull --dev` fetches",
            )
    return files


def read_bones_file(path: Path) -> dict[str, BoneLengths]:
    """The two bodies of a JSON file ``{"adversary": {bone: metres}, "opponent": {...}}``
    (names of `BoneLengths`; a bone left out takes its default).

    Raises:
        BadInput: naming the file and what is wrong with it.
    """
    try:
        document = json.loads(Path(path).read_text())
    except OSError as error:
        raise BadInput(str(path), f"cannot be read ({error.strerror or error})") from None
    except json.JSONDecodeError as error:
        raise BadInput(str(path), f"is not JSON ({error})") from None
    if not isinstance(document, dict) or set(document) != set(ROLES):
        raise BadInput(
            str(path),
            f'must be a JSON object with exactly the keys {list(ROLES)}, each {{"bone": metres}}',
        )
    known = {f.name for f in dataclasses.fields(BoneLengths)}
    bones = {}
    for role in ROLES:
        lengths = document[role]
        if not isinstance(lengths, dict):
            raise BadInput(str(path), f"{role} must be an object of bone lengths")
        unknown = sorted(set(lengths) - known)
        if unknown:
            raise BadInput(str(path), f"{role} has unknown bones {unknown}; known: {sorted(known)}")
        bad = [
            n
            for n, v in lengths.items()
            if not (isinstance(v, int | float) and not isinstance(v, bool) and 0 < v < 3)
        ]
        if bad:
            raise BadInput(str(path), f"{role}'s {bad} must be lengths in metres (0-3)")
        bones[role] = BoneLengths(**{n: float(v) for n, v in lengths.items()})
    return bones


def lifted_bones(
    con: duckdb.DuckDBPyConnection, video_id: str, what: str
) -> dict[str, BoneLengths]:
    """Both fighters' bones from the newest lift output of ``video_id`` (``what`` names the
    video in the error).

    Raises:
        BadInput: when the video has no lift output, or its lift found one fighter only.
    """
    found = newest_lift(con, video_id)
    if found is None:
        raise BadInput(
            what,
            "has not been lifted in this data directory: run `ringside process` on it first "
            "(`--until lift` will do), or give the bodies with --bones FILE",
        )
    bones = load_bones(con, video_id, found[0])
    missing = [role for role in ROLES if role not in bones]
    if missing:
        raise BadInput(
            what,
            f"its lift measured no {' and no '.join(missing)}: the synthetic adversary needs "
            "two bodies; give them with --bones FILE",
        )
    return {role: bones[role] for role in ROLES}


def motion_spec(
    config: SyntheticConfig, files: Mapping[str, str], bones: Mapping[str, BoneLengths]
) -> StageSpec:
    """The synthetic motion's output, a lift output of a pseudo video ``synthetic-…`` that the
    settings, the clips' bytes (``files``: name -> SHA-256) and the bodies name."""
    upstream = {
        "clips": dict(files),
        "bones": {role: dataclasses.asdict(bones[role]) for role in ROLES},
    }
    video_id = PREFIX + digest({"synthetic": config, **upstream})[:20]
    return StageSpec(LIFT, video_id, config, synthetic_code(), upstream)


def dataset_config(config: DatasetConfig, synthetic: SyntheticConfig) -> DatasetConfig:
    """The dataset stage's settings for the synthetic adversary: no time split (the windows
    split it) and no extra clips.

    Raises:
        BadInput: when ``dataset.min_clip_s`` is longer than a window (windows would be
            dropped and the split broken).
    """
    if config.min_clip_s > synthetic.window_s + 1e-9:
        raise BadInput(
            "dataset.min_clip_s",
            f"{config.min_clip_s:g} s is longer than the synthetic adversary's windows "
            f"({synthetic.window_s:g} s): its held-out windows would be dropped",
        )
    return dataclasses.replace(config, validation_fraction=0.0, extra_clips="")


# --------------------------------------------------------------------------------------------
# The performance: exchanges, windows, the split


@dataclass(frozen=True)
class Exchange:
    """One play of a clip, on the performance's step grid.

    Attributes:
        clip: its name (one of `CLIP_NAMES`).
        start: its first step.
        windows: (start, end, split) of each window, steps [start, end), split "train" or
            "validation".
    """

    clip: str
    start: int
    windows: tuple[tuple[int, int, str], ...]

    @property
    def end(self) -> int:
        return self.windows[-1][1]


def window_bounds(frames: int, window: int) -> list[tuple[int, int]]:
    """[start, end) of the windows of a clip of ``frames``: ``frames // window`` windows of
    ``window`` steps, the last taking the remainder.

    Raises:
        ValueError: when the clip is shorter than one window.
    """
    count = frames // window
    if count < 1:
        raise ValueError(f"a clip of {frames} frames is shorter than a window of {window} steps")
    ends = [window * (k + 1) for k in range(count - 1)] + [frames]
    return list(zip([0, *ends[:-1]], ends, strict=True))


def split_windows(
    groups: Sequence[object], fraction: float, rng: np.random.Generator
) -> np.ndarray:
    """Which windows are held out: round(``fraction`` x W) of the W windows, stratified by
    ``groups`` (one label per window): each group holds out floor(share) of its windows and the
    rest go, one each, to the groups with the largest remainders (ties drawn from ``rng``);
    within a group the windows are drawn from ``rng``.

    Returns:
        (W,) bool, True for a held-out window.
    """
    labels = list(groups)
    total = round(fraction * len(labels))
    names = list(dict.fromkeys(labels))
    members = {g: [i for i, label in enumerate(labels) if label == g] for g in names}
    share = np.array([fraction * len(members[g]) for g in names])
    count = np.floor(share).astype(int)
    left = total - int(count.sum())
    if left > 0:
        # Largest remainder first; `rng` breaks ties (and orders equal remainders).
        order = np.lexsort((rng.permutation(len(names)), -(share - count)))
        count[order[:left]] += 1
    held = np.zeros(len(labels), dtype=bool)
    for g, n in zip(names, count, strict=True):
        held[rng.permutation(members[g])[:n]] = True
    return held


def performance(frames: Mapping[str, int], config: SyntheticConfig) -> tuple[Exchange, ...]:
    """The exchanges, in order, and their windows' split.

    Args:
        frames: each clip's length in 30 Hz frames (all of `CLIP_NAMES`).
        config: the settings.
    """
    rng = np.random.default_rng(config.seed)
    order = [CLIP_NAMES[i] for _ in range(config.rounds) for i in rng.permutation(len(CLIP_NAMES))]
    bounds = [window_bounds(frames[name], config.window_steps) for name in order]
    groups = [(name, k) for name, b in zip(order, bounds, strict=True) for k in range(len(b))]
    held = iter(split_windows(groups, config.held_out_fraction, rng))
    exchanges, at = [], 0
    for name, windows in zip(order, bounds, strict=True):
        exchanges.append(
            Exchange(
                name,
                at,
                tuple(
                    (at + a, at + b, "validation" if next(held) else "train") for a, b in windows
                ),
            )
        )
        at += frames[name]
    return tuple(exchanges)


def pieces(exchanges: Sequence[Exchange]) -> list[tuple[int, int, str]]:
    """(start, end, split) of every run of one exchange's consecutive windows in one split: the
    clips the dataset stage cuts, each given a shot of its own."""
    found = []
    for exchange in exchanges:
        for start, end, split in exchange.windows:
            if (
                found
                and found[-1][1] == start
                and found[-1][2] == split
                and start != exchange.start
            ):
                found[-1] = (found[-1][0], end, split)
            else:
                found.append((start, end, split))
    return found


def shots_of(exchanges: Sequence[Exchange]) -> list[tuple[int, int, int]]:
    """The pieces as the dataset stage's shots, (shot, start_frame, end_frame) on a 30 fps
    grid (a frame is a step)."""
    return [(n, start, end) for n, (start, end, _) in enumerate(pieces(exchanges))]


# --------------------------------------------------------------------------------------------
# The motion


def moved(qpos: np.ndarray, yaw: float, shift: np.ndarray) -> np.ndarray:
    """(T, 35) ``qpos`` turned by ``yaw`` about the vertical through the world origin, then
    moved by ``shift`` (x, y) on the floor: one rigid move, the motion itself unchanged."""
    from scipy.spatial.transform import Rotation

    out = np.array(qpos, dtype=np.float64, copy=True)
    c, s = math.cos(yaw), math.sin(yaw)
    xy = out[:, :2] @ np.array([[c, -s], [s, c]]).T
    out[:, :2] = xy + shift
    turned = Rotation.from_euler("z", yaw) * Rotation.from_quat(out[:, 3:7], scalar_first=True)
    out[:, 3:7] = turned.as_quat(scalar_first=True)
    return out


def facing(qpos_a: np.ndarray, qpos_b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pelvis distance (T,) and how far each fighter's heading is from the other's pelvis,
    (T,) radians each, of two (T, 35) motions."""
    v = qpos_b[:, :2] - qpos_a[:, :2]
    bearing = np.arctan2(v[:, 1], v[:, 0])
    off_a = wrap_angle(bearing - heading_yaw(qpos_a[:, 3:7]))
    off_b = wrap_angle(bearing + np.pi - heading_yaw(qpos_b[:, 3:7]))
    return fighter_distance(qpos_a, qpos_b), off_a, off_b


def place_opponent(adversary: np.ndarray, opponent: np.ndarray, distance_m: float) -> np.ndarray:
    """``opponent`` (T, 35) moved rigidly on the floor to face ``adversary`` (T, 35) at
    ``distance_m``: the yaw and shift minimising the mean of (distance - ``distance_m``)^2 +
    0.25 (each fighter's facing error in rad)^2 over the frames, from the placement exact at the
    middle frame (Nelder-Mead; deterministic)."""
    from scipy.optimize import minimize

    if adversary.shape != opponent.shape:
        raise ValueError(
            f"adversary and opponent must be motions of equal length, got {adversary.shape} "
            f"and {opponent.shape}"
        )
    mid = len(adversary) // 2
    a_yaw = float(heading_yaw(adversary[mid, 3:7]))
    b_yaw = float(heading_yaw(opponent[mid, 3:7]))
    yaw0 = float(wrap_angle(a_yaw + np.pi - b_yaw))
    target = adversary[mid, :2] + distance_m * np.array([math.cos(a_yaw), math.sin(a_yaw)])
    shift0 = target - moved(opponent[mid : mid + 1], yaw0, np.zeros(2))[0, :2]

    def cost(p: np.ndarray) -> float:
        d, off_a, off_b = facing(adversary, moved(opponent, p[2], p[:2]))
        return float(np.mean((d - distance_m) ** 2 + _FACING_WEIGHT * (off_a**2 + off_b**2)))

    best = minimize(
        cost,
        np.r_[shift0, yaw0],
        method="Nelder-Mead",
        options={"xatol": 1e-4, "fatol": 1e-8, "maxiter": 2000},
    )
    return moved(opponent, best.x[2], best.x[:2])


def retargeted_clips(
    files: Mapping[str, Path], bones: Mapping[str, BoneLengths]
) -> dict[str, dict[str, np.ndarray]]:
    """Role -> clip name -> (T, 35) qpos of the clip retargeted onto that role's body."""
    from tasks import deepmimic

    clips = {name: deepmimic.load_deepmimic(path) for name, path in files.items()}
    return {
        role: {name: deepmimic.retarget(clip, body) for name, clip in clips.items()}
        for role, body in bones.items()
    }


def clip_frames(files: Mapping[str, Path]) -> dict[str, int]:
    """Each clip's length at 30 Hz (as `tasks.deepmimic.retarget` gives it, on any body)."""
    return {
        name: len(q) for name, q in retargeted_clips(files, {"any": BoneLengths()})["any"].items()
    }


def _fighter(
    qpos_parts: list[np.ndarray], steps: list[np.ndarray], bones: BoneLengths
) -> FighterMotion:
    """One fighter's motion from its exchanges' qpos: velocities and foot contacts within each
    exchange (none across a cut), keypoints at the humanoid's sites."""
    import mujoco

    from models.humanoid.compiled import keypoint_positions, velocities
    from tasks.lift.lifting import detect_contacts

    model = mujoco.MjModel.from_xml_string(boxer_mjcf(bones))
    joints = [keypoint_positions(model, q) for q in qpos_parts]
    return FighterMotion(
        step=np.concatenate(steps).astype(np.int64),
        qpos=np.concatenate(qpos_parts),
        qvel=np.concatenate([velocities(model, q, RATE) for q in qpos_parts]),
        joints=np.concatenate(joints),
        contacts=np.concatenate([detect_contacts(j, fps=RATE) for j in joints]),
        bones=bones,
    )


def synthetic_motion(
    clips: Mapping[str, Mapping[str, np.ndarray]],
    bones: Mapping[str, BoneLengths],
    exchanges: Sequence[Exchange],
    distance_m: float,
) -> dict[str, FighterMotion]:
    """Both fighters' motion over the performance: per exchange, the adversary's clip as
    retargeted and the opponent's the same clip reversed, placed by `place_opponent`.

    Args:
        clips: role -> clip name -> (T, 35) qpos on that role's body (`retargeted_clips`).
        bones: role -> the body the clips are on.
        exchanges: from `performance`.
        distance_m: the range the opponent is placed at.
    """
    parts: dict[str, list[np.ndarray]] = {role: [] for role in ROLES}
    steps = []
    # A clip's every play is the same pair of motions, so one placement serves them all.
    placed: dict[str, np.ndarray] = {}
    for exchange in exchanges:
        adversary = clips[ROLES[0]][exchange.clip]
        opponent = clips[ROLES[1]][exchange.clip][::-1]
        if len(adversary) != exchange.end - exchange.start:
            raise ValueError(
                f"clip {exchange.clip} has {len(adversary)} frames, its exchange "
                f"{exchange.end - exchange.start}"
            )
        parts[ROLES[0]].append(adversary)
        if exchange.clip not in placed:
            placed[exchange.clip] = place_opponent(adversary, opponent, distance_m)
        parts[ROLES[1]].append(placed[exchange.clip])
        steps.append(np.arange(exchange.start, exchange.end))
    return {role: _fighter(parts[role], steps, bones[role]) for role in ROLES}


def motion_output(
    motion: Mapping[str, FighterMotion], exchanges: Sequence[Exchange]
) -> StageOutput:
    """The synthetic lift output: ``lift_motion`` and ``lift_bones`` rows as the lift writes
    them, and metrics of the performance and of how the placement holds."""
    from tasks.lift.series import cleanup_series, motion_columns

    cuts = [e.start for e in exchanges[1:]]
    series = cleanup_series(motion, cuts=cuts)
    a, b = (motion[role] for role in ROLES)
    distance, off_a, off_b = facing(a.qpos, b.qpos)
    off = np.degrees(np.abs(np.concatenate([off_a, off_b])))
    windows = [w for e in exchanges for w in e.windows]
    slide = np.concatenate([series.fighters[r].contact_slide_m_s.ravel() for r in ROLES])
    slide = slide[np.isfinite(slide)]
    metrics = {
        "exchanges": float(len(exchanges)),
        "duration_s": exchanges[-1].end / RATE,
        "windows_train": float(sum(w[2] == "train" for w in windows)),
        "windows_held_out": float(sum(w[2] == "validation" for w in windows)),
        "distance_min_m": float(distance.min()),
        "distance_mean_m": float(distance.mean()),
        "distance_max_m": float(distance.max()),
        "facing_error_mean_deg": float(off.mean()),
        "facing_error_max_deg": float(off.max()),
        # Horizontal sole speed of feet in contact, per frame (the lift's foot skating).
        "contact_slide_cm_per_frame": float(slide.mean() * 100 / RATE) if len(slide) else 0.0,
    }
    return StageOutput(
        rows={
            "lift_motion": motion_columns(motion, series),
            "lift_bones": bone_rows({role: m.bones for role, m in motion.items()}),
        },
        metrics=metrics,
    )


def split_by_windows(output: StageOutput, exchanges: Sequence[Exchange]) -> StageOutput:
    """A dataset output made with no validation split (`build_dataset` with
    ``validation_fraction`` 0) with each clip, and its transitions, in the split of the windows
    it was cut from (`pieces`: the shots it was cut at)."""
    found = pieces(exchanges)
    starts = np.array([start for start, _, _ in found])
    clips: list[ClipRow] = []
    for row in output.rows["dataset_clips"]:
        start, end, split = found[int(np.searchsorted(starts, row.start_step, side="right")) - 1]
        if not start <= row.start_step < row.end_step <= end:
            raise ValueError(f"clip {row.clip} ({row.start_step}-{row.end_step}) crosses a window")
        clips.append(dataclasses.replace(row, split=split))
    transitions = dict(output.rows["dataset_transitions"])
    split_of = np.array([c.split for c in clips], dtype=object)
    transitions["split"] = split_of[transitions["clip"]].astype(str)
    rows = {**output.rows, "dataset_clips": clips, "dataset_transitions": transitions}
    return dataclasses.replace(output, rows=rows)
