"""The dataset stage for one video: clips, observation transitions, labels and statistics.

MAAIP (Younes et al. 2023, §3-4) trains on two demonstration sets: single-actor clips M^S (one
fighter's motion alone, for the motion prior D^M) and interaction clips M^I (both fighters, for
each agent's interaction prior D^I_i). From one video's lifted motion this makes both: every
unbroken run of a fighter's 30 Hz motion is a single-actor clip, every run where both fighters
were lifted an interaction clip (agent 0 the adversary, agent 1 the opponent). Runs are cut at
shot cuts (each shot has its own camera, hence its own world frame) and at the train/validation
boundary, the last ``validation_fraction`` of the video's time.

Each clip of T steps gives T - 1 transitions, computed by `models.humanoid.observations`, the
functions the training environment uses too.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.compiled import body_states, humanoid_index, velocities
from models.humanoid.kinematics import heading_frame
from models.humanoid.motion import RATE, FighterMotion, fighter_distance
from models.humanoid.observations import OPPONENT_DIM, BodyState, observation, self_observation
from models.pose.types import BLAZEPOSE_33
from storage.keys import code_version, digest
from tasks.dataset.bridging import bridge, gaps
from tasks.dataset.config import DatasetConfig
from tasks.dataset.labels import Punch, label_punches, label_steps
from tasks.dataset.statistics import FighterStatistics, combine, fighter_statistics
from tasks.dataset.store import (
    STAGE,
    ClipRow,
    DistributionRow,
    PunchRow,
    StatisticRow,
    StepRow,
)
from tasks.dataset.verdict import unusable_reason
from tasks.deepmimic import load_deepmimic, retarget
from tasks.errors import BadInput
from tasks.roles import AGENTS, ROLES
from tasks.runner import StageOutput, StageSpec

EXTRA = "extra"  # the role and agent (2) of clips the user adds
EXTRA_AGENT = 2
_ANKLES = [BLAZEPOSE_33.index("left_ankle"), BLAZEPOSE_33.index("right_ankle")]


def dataset_code() -> str:
    return code_version("tasks.dataset", "tasks.deepmimic", "models.humanoid")


def dataset_spec(config: DatasetConfig, video_id: str, lift_key: str) -> StageSpec:
    return StageSpec(STAGE, video_id, config, dataset_code(), {"lift": lift_key})


def extra_clips_spec(folder: Path, files: Mapping[str, str], bones: list[BoneLengths]) -> StageSpec:
    """The extra clips' output: ``files`` (name -> SHA-256) of ``folder`` retargeted onto the
    fighters' ``bones``, under a pseudo video id their bytes and the bones name."""
    upstream = {"files": dict(files), "bones": [dataclasses.asdict(b) for b in bones]}
    video_id = "extra-" + digest(upstream)[:20]
    # Not the folder: the same clips anywhere are the same output.
    return StageSpec(STAGE, video_id, {"extra_clips": "files"}, dataset_code(), upstream)


@dataclass(frozen=True)
class Clip:
    kind: str  # "single" | "interaction"
    role: str | None  # the fighter of a single clip
    shot: int
    split: str
    start: int  # first step
    end: int  # one past the last step

    @property
    def steps(self) -> np.ndarray:
        return np.arange(self.start, self.end)


def cut_clips(
    steps: np.ndarray,
    shot_of_step: np.ndarray,
    validation_from: int,
    min_steps: int,
    *,
    kind: str,
    role: str | None,
) -> list[Clip]:
    """Unbroken runs of ``steps``, cut where the shot or the split changes; short ones dropped.

    Args:
        steps: (N,) increasing step numbers where the motion exists.
        shot_of_step: (N,) the shot of each step.
        validation_from: first step of the validation split.
    """
    if len(steps) == 0:
        return []
    split = steps >= validation_from
    cut = (np.diff(steps) != 1) | (np.diff(shot_of_step) != 0) | (np.diff(split) != 0)
    starts = np.r_[0, np.flatnonzero(cut) + 1]
    ends = np.r_[starts[1:], len(steps)]
    return [
        Clip(
            kind,
            role,
            int(shot_of_step[a]),
            "validation" if split[a] else "train",
            int(steps[a]),
            int(steps[b - 1]) + 1,
        )
        for a, b in zip(starts, ends, strict=True)
        if b - a >= min_steps
    ]


def shot_of(steps: np.ndarray, shots: Sequence[tuple[int, int, int]], fps: float) -> np.ndarray:
    """The shot holding each step's video frame (shots are (shot, start_frame, end_frame))."""
    starts = np.array([s[1] for s in shots])
    numbers = np.array([s[0] for s in shots])
    frame = np.floor(steps / RATE * fps + 1e-6)
    return numbers[np.clip(np.searchsorted(starts, frame, side="right") - 1, 0, None)]


def _model(bones: BoneLengths) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(boxer_mjcf(bones))


def fighter_states(fighters: Mapping[str, FighterMotion]) -> dict[str, BodyState]:
    """Each fighter's body states over its steps, on a humanoid of its own bone lengths."""
    states = {}
    for role, motion in fighters.items():
        model = _model(motion.bones)
        states[role] = body_states(model, motion.qpos, motion.qvel, humanoid_index(model))
    return states


def _single_transitions(clip: Clip, motion: FighterMotion, state: BodyState, agent: int) -> dict:
    rows = motion.rows(clip.steps)
    own = self_observation(state[rows])
    return _columns(clip, agent, own[:-1], None, own[1:])


def _interaction_transitions(
    clip: Clip, fighters: Mapping[str, FighterMotion], states: Mapping[str, BodyState]
) -> list[dict]:
    at = {role: states[role][fighters[role].rows(clip.steps)] for role in ROLES}
    out = []
    for role, agent in AGENTS.items():
        other = ROLES[1 - ROLES.index(role)]
        full = observation(at[role], at[other])
        own, opp = full[:, :-OPPONENT_DIM], full[:, -OPPONENT_DIM:]
        out.append(_columns(clip, agent, own[:-1], opp[:-1], own[1:]))
    return out


def _columns(clip: Clip, agent: int, own, opp, next_own) -> dict:
    n = len(own)
    columns = {
        "kind": np.array([clip.kind] * n),
        "agent": np.full(n, agent, dtype=np.int8),
        "split": np.array([clip.split] * n),
        "clip": np.full(n, -1, dtype=np.int32),  # filled in when clips are numbered
        "step": np.arange(clip.start, clip.start + n, dtype=np.int32),
        "self": own.astype(np.float32),
        "next_self": next_own.astype(np.float32),
    }
    if opp is not None:
        columns["opp"] = opp.astype(np.float32)
    return columns


def _concat(parts: list[dict]) -> dict:
    """Transition columns of several clips as one; single clips' missing opp becomes NULL."""
    if not parts:
        return {}
    n = sum(len(p["step"]) for p in parts)
    opp = np.empty(n, dtype=object)
    at = 0
    for p in parts:
        count = len(p["step"])
        if "opp" in p:
            opp[at : at + count] = list(p["opp"])
        at += count
    names = [k for k in parts[0] if k != "opp"]
    out = {k: np.concatenate([p[k] for p in parts]) for k in names}
    out["opp"] = opp
    return out


def _punch_rows(
    role: str,
    punches: list[tuple[Clip, Punch]],
    fighters: Mapping[str, FighterMotion],
) -> list[PunchRow]:
    other = ROLES[1 - ROLES.index(role)] if role in ROLES else None
    present = set(fighters[other].step.tolist()) if other in fighters else set()
    rows = []
    for number, (clip, punch) in enumerate(punches):
        peak_step = clip.start + punch.peak
        local = None
        if peak_step in present:
            row = fighters[other].rows(np.array([peak_step]))[0]
            them = fighters[other].qpos[row]
            heading = heading_frame(them[3:7])
            local = (heading.T @ (punch.target - them[:3])).tolist()
        rows.append(
            PunchRow(
                role,
                number,
                punch.hand,
                punch.kind,
                clip.start + punch.start,
                peak_step,
                clip.start + punch.end,
                float(punch.extension_m),
                np.asarray(punch.target, dtype=float).tolist(),
                local,
            )
        )
    return rows


def _label_fighter(
    role: str,
    clips: list[Clip],
    fighters: Mapping[str, FighterMotion],
    config: DatasetConfig,
) -> tuple[list[tuple[Clip, Punch]], list[StepRow], FighterStatistics | None]:
    """Punches, step rows and statistics of one fighter over its single clips."""
    motion = fighters[role]
    arm = motion.bones.upper_arm + motion.bones.forearm
    other = ROLES[1 - ROLES.index(role)]
    punches: list[tuple[Clip, Punch]] = []
    steps: list[StepRow] = []
    stats: list[FighterStatistics] = []
    durations: list[float] = []
    for clip in clips:
        rows = motion.rows(clip.steps)
        keypoints = motion.joints[rows]
        quat = motion.qpos[rows, 3:7]
        found = label_punches(keypoints, quat, RATE, config.punch, arm_m=arm)
        walked = label_steps(motion.contacts[rows], keypoints[:, _ANKLES])
        punches.extend((clip, p) for p in found)
        steps.extend(
            StepRow(
                role,
                s.foot,
                clip.start + s.lift_off,
                clip.start + s.touch_down,
                float(s.length_m),
            )
            for s in walked
        )
        opponent_root = None
        if other in fighters and np.isin(clip.steps, fighters[other].step).all():
            opponent_root = fighters[other].qpos[fighters[other].rows(clip.steps), :3]
        stats.append(
            fighter_statistics(
                punches=found,
                steps=walked,
                keypoints=keypoints,
                root_pos=motion.qpos[rows, :3],
                root_quat=quat,
                opponent_root=opponent_root,
                rate=RATE,
            )
        )
        durations.append(len(rows) / RATE)
    return punches, steps, (combine(stats, durations) if stats else None)


def implausible_steps(
    fighters: Mapping[str, FighterMotion], config: DatasetConfig
) -> dict[str, np.ndarray]:
    """Per fighter, which of its steps (a bool per row) no boxer could have made: the pelvis
    faster than ``max_root_speed_m_s``, or the two fighters further apart than
    ``max_fighter_distance_m`` (both fighters' steps)."""
    bad = {
        role: np.linalg.norm(m.qvel[:, :3], axis=1) > config.max_root_speed_m_s
        for role, m in fighters.items()
    }
    if all(r in fighters for r in ROLES):
        a, b = (fighters[r] for r in ROLES)
        both, in_a, in_b = np.intersect1d(a.step, b.step, return_indices=True)
        apart = fighter_distance(a.qpos[in_a], b.qpos[in_b]) > config.max_fighter_distance_m
        bad[ROLES[0]][in_a[apart]] = True
        bad[ROLES[1]][in_b[apart]] = True
    return bad


def _without(motion: FighterMotion, drop: np.ndarray) -> FighterMotion:
    keep = ~drop
    return dataclasses.replace(
        motion,
        step=motion.step[keep],
        qpos=motion.qpos[keep],
        qvel=motion.qvel[keep],
        joints=motion.joints[keep],
        contacts=motion.contacts[keep],
    )


def build_dataset(
    fighters: Mapping[str, FighterMotion],
    *,
    shots: Sequence[tuple[int, int, int]],
    fps: float,
    config: DatasetConfig,
) -> StageOutput:
    """The dataset rows and metrics of one video's lifted motion.

    Args:
        fighters: role -> its motion (the lift output's roles).
        shots: the video's (shot, start_frame, end_frame) ranges.
        fps: the video's frame rate.
        config: the stage's settings.

    Raises:
        BadInput: when no fighter has a clip of ``min_clip_s``.
    """
    # The last guard before training: steps no boxer could have made become gaps.
    implausible = implausible_steps(fighters, config)
    fighters = {role: _without(m, implausible[role]) for role, m in fighters.items()}
    dropped = int(sum(d.sum() for d in implausible.values()))
    notes = []
    if dropped:
        notes.append(
            f"{dropped} steps left out as implausible: a pelvis faster than "
            f"{config.max_root_speed_m_s:g} m/s or fighters more than "
            f"{config.max_fighter_distance_m:g} m apart (dataset.max_root_speed_m_s, "
            "dataset.max_fighter_distance_m)"
        )
    fighters = {role: m for role, m in fighters.items() if len(m.step)}
    min_steps = max(2, math.ceil(config.min_clip_s * RATE))
    last = max(int(m.step.max()) for m in fighters.values() if len(m.step))
    validation_from = math.ceil((last + 1) * (1 - config.validation_fraction))
    bridged = 0
    for role, motion in fighters.items():
        spans = gaps(
            motion.step, shot_of(motion.step, shots, fps), validation_from, config.max_bridge_steps
        )
        if spans:  # the humanoid is compiled only for a fighter with a gap to fill
            fighters[role] = bridge(motion, spans, _model(motion.bones))
            bridged += sum(b - a for a, b in spans)
    clips: list[Clip] = []
    for role, motion in fighters.items():
        shot = shot_of(motion.step, shots, fps)
        clips += cut_clips(motion.step, shot, validation_from, min_steps, kind="single", role=role)
    if all(r in fighters for r in ROLES):
        both = np.intersect1d(fighters[ROLES[0]].step, fighters[ROLES[1]].step)
        clips += cut_clips(
            both,
            shot_of(both, shots, fps),
            validation_from,
            min_steps,
            kind="interaction",
            role=None,
        )
    if not clips:
        raise BadInput(
            STAGE,
            f"no fighter was lifted for {config.min_clip_s} s without a break "
            f"(dataset.min_clip_s); no clips to learn from",
        )
    # Said here as well as when the dataset is assembled: with other videos of the adversary
    # the dataset may be usable, and this video's share of it none.
    alone = unusable_reason((c.kind, c.role, c.split, c.end - c.start) for c in clips)
    if alone is not None:
        notes.append(f"this video alone cannot be trained on: {alone}")
    states = fighter_states(fighters)
    parts = []
    for number, clip in enumerate(clips):
        if clip.kind == "single":
            made = [
                _single_transitions(clip, fighters[clip.role], states[clip.role], AGENTS[clip.role])
            ]
        else:
            made = _interaction_transitions(clip, fighters, states)
        for part in made:
            part["clip"][:] = number
        parts += made
    order = {"single": 0, "interaction": 1}
    parts.sort(key=lambda p: (order[p["kind"][0]], int(p["agent"][0]), int(p["clip"][0])))
    transitions = _concat(parts)

    punch_rows, step_rows, statistics = [], [], {}
    for role in fighters:
        own = [c for c in clips if c.kind == "single" and c.role == role]
        punches, steps, stats = _label_fighter(role, own, fighters, config)
        punch_rows += _punch_rows(role, punches, fighters)
        step_rows += steps
        if stats is not None:
            statistics[role] = stats
    return StageOutput(
        rows={
            "dataset_clips": _clip_rows(clips),
            "dataset_transitions": transitions,
            "dataset_punches": punch_rows,
            "dataset_steps": step_rows,
            "dataset_statistics": [
                StatisticRow(role, name, float(value))
                for role, s in statistics.items()
                for name, value in s.scalars.items()
            ],
            "dataset_distributions": [
                DistributionRow(role, name, np.asarray(values, dtype=float).tolist())
                for role, s in statistics.items()
                for name, values in s.distributions.items()
            ],
        },
        metrics={
            **_metrics(clips, transitions, punch_rows, statistics),
            "steps_rejected": dropped,
            "steps_bridged": bridged,
        },
        notes=tuple(notes),
    )


def _clip_rows(clips: list[Clip]) -> list[ClipRow]:
    return [
        ClipRow(n, c.kind, c.role, c.shot, c.split, c.start, c.end) for n, c in enumerate(clips)
    ]


def _metrics(
    clips: list[Clip], transitions: Mapping, punch_rows: list, statistics: Mapping
) -> dict[str, float]:
    metrics = {
        "clips_single": float(sum(c.kind == "single" for c in clips)),
        "clips_interaction": float(sum(c.kind == "interaction" for c in clips)),
        "transitions": float(len(transitions.get("step", ()))),
        "punches": float(len(punch_rows)),
        "minutes_interaction": sum(c.end - c.start for c in clips if c.kind == "interaction")
        / RATE
        / 60,
    }
    for role in ROLES:
        single = [c for c in clips if c.kind == "single" and c.role == role]
        metrics[f"{role}_minutes_single"] = sum(c.end - c.start for c in single) / RATE / 60
    for role, stats in statistics.items():
        for name, value in stats.scalars.items():
            metrics[f"{role}_{name}"] = float(value)
    return {k: float(v) for k, v in metrics.items() if math.isfinite(v)}


def extra_clip_output(folder: Path, bones: Sequence[BoneLengths]) -> StageOutput:
    """Single-actor clips (agent 2) from the DeepMimic-format motion files in ``folder``, each
    retargeted (`tasks.deepmimic.retarget`, 30 Hz) onto every body in ``bones`` (the
    dataset's fighters), so that the motion prior sees them on the humanoids it judges; the
    default body when ``bones`` is empty.
    """
    files = sorted(folder.glob("*.txt"))
    if not files:
        raise BadInput(str(folder), "no *.txt motion clips in this folder (dataset.extra_clips)")
    clips, parts = [], []
    for body in bones or [BoneLengths()]:
        model = _model(body)
        index = humanoid_index(model)
        for path in files:
            number = len(clips)
            qpos = retarget(load_deepmimic(path), body)
            qvel = velocities(model, qpos, RATE)
            clip = Clip("single", EXTRA, number, "train", 0, len(qpos))
            own = self_observation(body_states(model, qpos, qvel, index))
            part = _columns(clip, EXTRA_AGENT, own[:-1], None, own[1:])
            part["clip"][:] = number
            clips.append(clip)
            parts.append(part)
    transitions = _concat(parts)
    return StageOutput(
        rows={
            "dataset_clips": _clip_rows(clips),
            "dataset_transitions": transitions,
        },
        metrics={
            "clips_single": float(len(clips)),
            "clips_interaction": 0.0,
            "transitions": float(len(transitions["step"])),
            "punches": 0.0,
            "extra_minutes_single": sum(c.end for c in clips) / RATE / 60,
        },
    )
