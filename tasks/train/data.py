"""What training reads from a dataset: demonstration transitions, start states, the fighters.

MAAIP's priors learn from the dataset stage's transitions (`tasks.dataset.store`): the motion
prior D^M from every single-actor transition (o^self_t, o^self_t+1), the interaction prior D^I_i
from agent i's side of the interaction clips (o_t, o^self_t+1). Episodes start from frames of the
interaction clips (reference state initialisation), both fighters as in the footage, on
humanoids with the fighters' own bone lengths.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import duckdb
import mujoco
import numpy as np

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.kinematics import humanoid_index, joint_targets_to_action
from models.humanoid.observations import (
    OBSERVATION_DIM,
    SELF_DIM,
    body_states,
    joint_angles,
    observation,
)
from tasks.dataset.stage import ROLES
from tasks.dataset.store import dataset_info, load_transitions, upstream_lift_key
from tasks.errors import BadInput
from tasks.lift.motion import RATE, velocities
from tasks.lift.store import load_motion
from tasks.lift.synthetic import clip_path, load_deepmimic, retarget
from tasks.train.env import ReferenceMotions, facing_reference


@dataclass(frozen=True, eq=False)
class Demonstrations:
    """One dataset, ready for training.

    Attributes:
        dataset_key: the dataset's key.
        motion: (M, 446) single-actor transitions [o^self_t, o^self_t+1] (M^S).
        interaction: per agent, (M_i, 497) transitions [o_t, o^self_t+1] (agent i's side of M^I).
        reference: interaction frames of both fighters to start episodes from.
        bones: the adversary's and the opponent's bone lengths (agents 0 and 1).
    """

    dataset_key: str
    motion: np.ndarray
    interaction: tuple[np.ndarray, np.ndarray]
    reference: ReferenceMotions
    bones: tuple[BoneLengths, BoneLengths]


def _pairs(con: duckdb.DuckDBPyConnection, dataset_key: str, kind: str, agent) -> np.ndarray:
    found = load_transitions(con, dataset_key, kind=kind, agent=agent)
    return np.concatenate([found.obs, found.next_self], axis=1)


def load_demonstrations(con: duckdb.DuckDBPyConnection, dataset_key: str) -> Demonstrations:
    """Everything training needs from dataset ``dataset_key`` (its train split).

    Raises:
        UnknownDataset: no such dataset.
        BadInput: the dataset has no interaction clip to learn from or start episodes in.
    """
    info = dataset_info(con, dataset_key)
    motion = _pairs(con, dataset_key, "single", None)
    interaction = tuple(_pairs(con, dataset_key, "interaction", a) for a in (0, 1))
    frames: list[tuple[np.ndarray, ...]] = []
    bones, most = None, -1
    for video_id, key in info.members:
        lift_key = upstream_lift_key(con, video_id, key)
        if lift_key is None:  # extra single-actor clips: no interaction
            continue
        clips = con.execute(
            "SELECT start_step, end_step FROM dataset_clips WHERE key = ? AND video_id = ? "
            "AND kind = 'interaction' AND split = 'train' ORDER BY clip",
            [key, video_id],
        ).fetchall()
        if not clips:
            continue
        fighters = load_motion(con, video_id, lift_key)
        steps = np.concatenate([np.arange(a, b) for a, b in clips])
        rows = {role: fighters[role].rows(steps) for role in ROLES}
        frames.append(
            tuple(getattr(fighters[r], f)[rows[r]] for r in ROLES for f in ("qpos", "qvel"))
        )
        if len(steps) > most:
            most, bones = len(steps), (fighters[ROLES[0]].bones, fighters[ROLES[1]].bones)
    if not frames or min(len(x) for x in interaction) == 0:
        raise BadInput(
            f"dataset {dataset_key}",
            "has no interaction clips in its train split: nothing to learn interactions from "
            "or to start episodes in (lower dataset.min_clip_s or add footage)",
        )
    q0, v0, q1, v1 = (np.concatenate([f[i] for f in frames]) for i in range(4))
    return Demonstrations(
        dataset_key=dataset_key,
        motion=motion,
        interaction=interaction,
        reference=ReferenceMotions(qpos0=q0, qvel0=v0, qpos1=q1, qvel1=v1),
        bones=bones,
    )


def demonstrations_from_reference(
    reference: ReferenceMotions, bones: tuple[BoneLengths, BoneLengths], *, key: str
) -> Demonstrations:
    """Demonstrations made from one interaction given as arrays, without a database.

    The transitions are computed as the dataset stage computes them (the shared observation
    functions on each fighter's own humanoid); both fighters' motions form the single-actor
    set. For benchmarks and tests that train on a motion clip, e.g. `facing_reference`.
    """
    states = []
    for agent, (qpos, qvel) in enumerate(
        ((reference.qpos0, reference.qvel0), (reference.qpos1, reference.qvel1))
    ):
        model = mujoco.MjModel.from_xml_string(boxer_mjcf(bones[agent]))
        states.append(body_states(model, qpos, qvel, humanoid_index(model)))
    obs = [observation(states[0], states[1]), observation(states[1], states[0])]
    motion = np.concatenate([np.concatenate([o[:-1, :SELF_DIM], o[1:, :SELF_DIM]], 1) for o in obs])
    interaction = tuple(
        np.concatenate([o[:-1], o[1:, :SELF_DIM]], 1).astype(np.float32) for o in obs
    )
    return Demonstrations(key, motion.astype(np.float32), interaction, reference, bones)


def clip_demonstrations(
    assets: Path,
    clip: str = "punch",
    bones: tuple[BoneLengths, BoneLengths] = (BoneLengths(), BoneLengths()),  # noqa: B008
) -> Demonstrations:
    """A DeepMimic sample clip performed by two fighters facing each other
    (`facing_reference`), as a dataset would hold it: training without footage, for tests and
    benchmarks. Key "clip:<clip>"."""
    qpos = retarget(load_deepmimic(clip_path(assets, clip)))
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(bones[0]))
    reference = facing_reference(qpos, velocities(model, qpos, RATE))
    return demonstrations_from_reference(reference, bones, key=f"clip:{clip}")


@dataclass(frozen=True, eq=False)
class ClonedActions:
    """Behaviour cloning's samples: what each demonstration's fighter observed and the PD-target
    actions that reach its next pose.

    Attributes:
        obs: (B, 274) observations o_t. Single-actor transitions have no opponent: theirs is the
            mean opponent block of the interaction transitions (a typical opponent).
        agent: (B,) the agent each row is cloned for (single-actor rows appear for both).
        actions: (B, 28) the actions whose hinge targets are the next observation's joint angles.
    """

    obs: np.ndarray
    agent: np.ndarray
    actions: np.ndarray


def cloned_actions(demos: Demonstrations) -> ClonedActions:
    """Behaviour cloning samples from every demonstration transition (`ClonedActions`)."""
    obs, agents, nxt = [], [], []
    for agent, rows in enumerate(demos.interaction):
        obs.append(rows[:, :OBSERVATION_DIM])
        agents.append(np.full(len(rows), agent))
        nxt.append(rows[:, OBSERVATION_DIM:])
    opponent = np.concatenate(obs)[:, SELF_DIM:].mean(axis=0)
    single = np.concatenate(
        [demos.motion[:, :SELF_DIM], np.broadcast_to(opponent, (len(demos.motion), len(opponent)))],
        axis=1,
    )
    for agent in range(2):
        obs.append(single)
        agents.append(np.full(len(single), agent))
        nxt.append(demos.motion[:, SELF_DIM:])
    next_self = np.concatenate(nxt)
    return ClonedActions(
        obs=np.concatenate(obs).astype(np.float32),
        agent=np.concatenate(agents),
        actions=joint_targets_to_action(joint_angles(next_self)).astype(np.float32),
    )
