"""Reading and writing the dataset tables: lifted motion in, assembled datasets, transitions out.

A dataset (what one training run learns from) joins the per-video dataset outputs of one
adversary's footage made with one config and code version. Its key is a hash of the members'
output keys and the settings, so a rerun with nothing changed gives the same key and changing
any setting gives a new one.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass

import duckdb
import numpy as np

from models.humanoid.boxer import BoneLengths
from models.humanoid.observations import OPPONENT_DIM, SELF_DIM
from storage.db import transact, utcnow
from storage.keys import digest, stable_json
from storage.records import insert_rows
from tasks.dataset.config import DatasetConfig
from tasks.dataset.statistics import FighterStatistics, combine_videos
from tasks.dataset.verdict import unusable_reason
from tasks.errors import BadInput
from tasks.lift.store import load_bones, load_motion
from tasks.roles import AGENTS, ROLES

STAGE = "dataset"


@dataclass(frozen=True)
class ClipRow:
    """A ``dataset_clips`` row: a clip of one fighter ('single') or both ('interaction')."""

    clip: int
    kind: str
    role: str | None
    shot: int
    split: str
    start_step: int
    end_step: int


@dataclass(frozen=True)
class PunchRow:
    """A ``dataset_punches`` row; the target is the wrist at full extension, in the world and
    in the other fighter's heading frame when he is there."""

    role: str
    punch: int
    hand: str
    kind: str
    start_step: int
    peak_step: int
    end_step: int
    extension_m: float
    target: list[float]
    target_local: list[float] | None


@dataclass(frozen=True)
class StepRow:
    """A ``dataset_steps`` row."""

    role: str
    foot: str
    lift_off_step: int
    touch_down_step: int
    length_m: float


@dataclass(frozen=True)
class StatisticRow:
    """A ``dataset_statistics`` row: one number of a fighter's statistics."""

    role: str
    name: str
    value: float


@dataclass(frozen=True)
class DistributionRow:
    """A ``dataset_distributions`` row: one distribution of a fighter's statistics."""

    role: str
    name: str
    samples: list[float]


class UnknownDataset(KeyError):
    """A dataset key that was never assembled."""

    def __str__(self) -> str:
        return str(self.args[0])


def candidate_members(
    con: duckdb.DuckDBPyConnection, adversary: str, config: DatasetConfig, code: str
) -> list[tuple[str, str]]:
    """(video_id, key) of the newest dataset output, made with ``config`` and ``code``, of each
    video whose adversary is ``adversary``."""
    return [
        tuple(row)
        for row in con.execute(
            """
            SELECT o.video_id, o.key FROM stage_outputs o
            WHERE o.stage = ? AND o.config = ? AND o.code_version = ?
              AND o.video_id IN (SELECT video_id FROM ingest_adversaries WHERE name = ?)
            QUALIFY row_number() OVER (PARTITION BY o.video_id ORDER BY o.created_at DESC) = 1
            ORDER BY o.video_id
            """,
            [STAGE, stable_json(config), code, adversary],
        ).fetchall()
    ]


def upstream_lift_key(con: duckdb.DuckDBPyConnection, video_id: str, key: str) -> str | None:
    """The lift output dataset output ``key`` of ``video_id`` was made from; None for outputs
    that come from no lift (extra clips)."""
    row = con.execute(
        "SELECT upstream FROM stage_outputs WHERE stage = ? AND video_id = ? AND key = ?",
        [STAGE, video_id, key],
    ).fetchone()
    return json.loads(row[0]).get("lift") if row else None


def member_bones(
    con: duckdb.DuckDBPyConnection, members: list[tuple[str, str]]
) -> list[BoneLengths]:
    """The bones of every fighter of the ``members`` (video_id, dataset output key) that come
    from footage, in member and role order, each set once."""
    found: list[BoneLengths] = []
    for video_id, key in members:
        lift_key = upstream_lift_key(con, video_id, key)
        if lift_key is None:
            continue
        for _, bones in sorted(load_bones(con, video_id, lift_key).items()):
            if bones not in found:
                found.append(bones)
    return found


def assembled_key(adversary: str, config: DatasetConfig, members: list[tuple[str, str]]) -> str:
    return digest({"adversary": adversary, "config": config, "members": sorted(members)})[:24]


def record_dataset(
    con: duckdb.DuckDBPyConnection,
    adversary: str,
    config: DatasetConfig,
    members: list[tuple[str, str]],
) -> tuple[str, bool]:
    """Record the dataset joining ``members``; returns its key and whether it is new."""
    if not members:
        raise ValueError(f"no dataset outputs to assemble for adversary {adversary!r}")
    key = assembled_key(adversary, config, members)

    def record(con: duckdb.DuckDBPyConnection) -> bool:
        exists = con.execute("SELECT 1 FROM datasets WHERE dataset_key = ?", [key]).fetchone()
        if exists:
            return False
        con.execute(
            "INSERT INTO datasets VALUES (?, ?, ?, ?)",
            [key, adversary, stable_json(config), utcnow()],
        )
        insert_rows(
            con,
            "INSERT INTO dataset_members",
            [[key, video_id, output] for video_id, output in members],
        )
        return True

    return key, transact(con, record)


@dataclass(frozen=True)
class DatasetInfo:
    dataset_key: str
    adversary: str
    config: dict
    created_at: object
    members: tuple[tuple[str, str], ...]


def dataset_info(con: duckdb.DuckDBPyConnection, dataset_key: str) -> DatasetInfo:
    """What dataset ``dataset_key`` (or the one key it is a prefix of) is; UnknownDataset
    (listing the known keys) if none or several match."""
    rows = con.execute(
        "SELECT dataset_key, adversary, config, created_at FROM datasets "
        "WHERE starts_with(dataset_key, ?) ORDER BY dataset_key",
        [dataset_key],
    ).fetchall()
    if len(rows) != 1:
        known = [r[0] for r in con.execute("SELECT dataset_key FROM datasets").fetchall()]
        problem = "no dataset" if not rows else "several datasets start with"
        raise UnknownDataset(
            f"{problem} {dataset_key!r}; known: {', '.join(known) or 'none'} "
            f"(`ringside datasets` lists them)"
        )
    dataset_key, *row = rows[0]
    members = con.execute(
        "SELECT video_id, key FROM dataset_members WHERE dataset_key = ? ORDER BY video_id",
        [dataset_key],
    ).fetchall()
    return DatasetInfo(dataset_key, row[0], json.loads(row[1]), row[2], tuple(members))


def member_statistics(
    con: duckdb.DuckDBPyConnection, dataset_key: str
) -> tuple[list[tuple[str, str, str, float]], dict[str, FighterStatistics]]:
    """Dataset ``dataset_key``'s fighter statistics: every member video's scalar rows
    (video_id, role, name, value), and per role its statistics over all of them combined
    (`statistics.combine_videos`). Both empty for a dataset with no statistics."""
    scalars = con.execute(
        """
        SELECT s.video_id, s.role, s.name, s.value FROM dataset_statistics s
        JOIN dataset_members m ON m.key = s.key AND m.video_id = s.video_id
        WHERE m.dataset_key = ? ORDER BY ALL
        """,
        [dataset_key],
    ).fetchall()
    samples = con.execute(
        """
        SELECT d.video_id, d.role, d.name, d.samples FROM dataset_distributions d
        JOIN dataset_members m ON m.key = d.key AND m.video_id = d.video_id
        WHERE m.dataset_key = ? ORDER BY ALL
        """,
        [dataset_key],
    ).fetchall()
    return scalars, combine_videos(scalars, samples)


def dataset_verdicts(con: duckdb.DuckDBPyConnection) -> dict[str, str | None]:
    """Per assembled dataset, why it cannot be trained on (`verdict.unusable_reason` of its
    members' clips), None when it can."""
    clips: dict[str, list] = {
        key: [] for (key,) in con.execute("SELECT dataset_key FROM datasets").fetchall()
    }
    for key, *clip in con.execute(
        """
        SELECT m.dataset_key, c.kind, c.role, c.split, c.end_step - c.start_step
        FROM dataset_members m JOIN dataset_clips c ON c.key = m.key AND c.video_id = m.video_id
        """
    ).fetchall():
        clips[key].append(clip)
    return {key: unusable_reason(found) for key, found in clips.items()}


def list_datasets(con: duckdb.DuckDBPyConnection) -> list[dict]:
    """Every assembled dataset, newest first, with its size and, when it cannot be trained on,
    why (``unusable``; None when it can)."""
    rows = con.execute(
        """
        SELECT d.dataset_key, d.adversary, d.created_at, count(DISTINCT m.video_id) AS videos,
               (SELECT count(*) FROM dataset_transitions t JOIN dataset_members n
                  ON t.key = n.key AND t.video_id = n.video_id
                WHERE n.dataset_key = d.dataset_key) AS transitions
        FROM datasets d JOIN dataset_members m USING (dataset_key)
        GROUP BY ALL ORDER BY d.created_at DESC
        """
    ).fetchall()
    names = ("dataset_key", "adversary", "created_at", "videos", "transitions")
    verdicts = dataset_verdicts(con)
    return [{**dict(zip(names, r, strict=True)), "unusable": verdicts[r[0]]} for r in rows]


@dataclass(frozen=True, eq=False)
class Transitions:
    """Demonstration transitions as float32 arrays, one row each.

    ``obs`` is o^self_t (223) for the motion prior or o_t = [o^self, o^opp] (274) for an
    interaction prior; ``next_self`` is o^self_t+1.
    """

    obs: np.ndarray
    next_self: np.ndarray

    def __len__(self) -> int:
        return len(self.obs)


_KINDS = ("single", "interaction")


def _selection(kind: str, agent: int | None, split: str) -> tuple[str, list]:
    """The WHERE clause (after the output's key and video) and its parameters."""
    if kind not in _KINDS:
        raise ValueError(f"kind must be one of {_KINDS}, got {kind!r}")
    if split not in ("train", "validation"):
        raise ValueError(f"split must be 'train' or 'validation', got {split!r}")
    if kind == "interaction" and agent not in AGENTS.values():
        raise ValueError(f"interaction transitions need agent 0 or 1, got {agent!r}")
    where, params = "kind = ? AND split = ?", [kind, split]
    if agent is not None:
        where, params = where + " AND agent = ?", [*params, agent]
    return where, params


def count_transitions(
    con: duckdb.DuckDBPyConnection,
    dataset_key: str,
    *,
    kind: str,
    agent: int | None = None,
    split: str = "train",
) -> int:
    """How many transitions `iter_transitions` would yield (one query over the members)."""
    dataset_info(con, dataset_key)
    where, params = _selection(kind, agent, split)
    return con.execute(
        f"SELECT count(*) FROM dataset_transitions t JOIN dataset_members m "
        f"ON t.key = m.key AND t.video_id = m.video_id WHERE m.dataset_key = ? AND {where}",
        [dataset_key, *params],
    ).fetchone()[0]


def iter_transitions(
    con: duckdb.DuckDBPyConnection,
    dataset_key: str,
    *,
    kind: str,
    agent: int | None = None,
    split: str = "train",
) -> Iterator[Transitions]:
    """The transitions of a dataset, one member video at a time (so memory holds one video's).

    Single-actor transitions (the motion prior's M^S) of every fighter unless ``agent`` names
    one (0 adversary, 1 opponent, 2 extra clips); interaction transitions (M^I) of ``agent``,
    whose ``obs`` is [o^self, o^opp]. Each batch is in (agent, clip, step) order.
    """
    info = dataset_info(con, dataset_key)
    where, params = _selection(kind, agent, split)
    # As variable-length lists, which DuckDB hands to numpy faster than fixed-size arrays.
    names = ("self", "opp", "next_self") if kind == "interaction" else ("self", "next_self")
    columns = ", ".join(f"{n}::FLOAT[] AS {n}" for n in names)
    for video_id, key in info.members:
        # No ORDER BY: an output's rows were inserted in (kind, agent, clip, step) order and
        # DuckDB returns a scan in insertion order (preserve_insertion_order, on by default);
        # sorting again took 60 % of the read (benchmarks/dataset_io.py).
        found = con.execute(
            f"SELECT {columns} FROM dataset_transitions WHERE key = ? AND video_id = ? AND {where}",
            [key, video_id, *params],
        ).fetchnumpy()
        if len(found["self"]) == 0:
            continue
        obs = np.stack(found["self"])
        if kind == "interaction":
            obs = np.concatenate([obs, np.stack(found["opp"])], axis=1)
        yield Transitions(obs, np.stack(found["next_self"]))


def load_transitions(
    con: duckdb.DuckDBPyConnection,
    dataset_key: str,
    *,
    kind: str,
    agent: int | None = None,
    split: str = "train",
) -> Transitions:
    """All transitions `iter_transitions` yields, as one pair of float32 arrays, filled batch
    by batch into arrays allocated once."""
    total = count_transitions(con, dataset_key, kind=kind, agent=agent, split=split)
    width = SELF_DIM + (OPPONENT_DIM if kind == "interaction" else 0)
    obs = np.empty((total, width), np.float32)
    next_self = np.empty((total, SELF_DIM), np.float32)
    at = 0
    for batch in iter_transitions(con, dataset_key, kind=kind, agent=agent, split=split):
        obs[at : at + len(batch)] = batch.obs
        next_self[at : at + len(batch)] = batch.next_self
        at += len(batch)
    if at != total:
        raise RuntimeError(f"dataset {dataset_key} changed while it was read ({at} of {total})")
    return Transitions(obs, next_self)


def _pairs(
    con: duckdb.DuckDBPyConnection, dataset_key: str, kind: str, agent, split: str = "train"
) -> np.ndarray:
    found = load_transitions(con, dataset_key, kind=kind, agent=agent, split=split)
    return np.concatenate([found.obs, found.next_self], axis=1)


def interaction_clips(
    con: duckdb.DuckDBPyConnection, members: tuple[tuple[str, str], ...], split: str = "train"
) -> Iterator[tuple[str, str, list[tuple[int, int]]]]:
    """(video_id, lift key, [(start_step, end_step)]) of each member, in member order, that has
    interaction clips in its ``split`` (extra single-actor clips come from no lift and have
    none)."""
    for video_id, key in members:
        lift_key = upstream_lift_key(con, video_id, key)
        if lift_key is None:
            continue
        clips = con.execute(
            "SELECT start_step, end_step FROM dataset_clips WHERE key = ? AND video_id = ? "
            "AND kind = 'interaction' AND split = ? ORDER BY clip",
            [key, video_id, split],
        ).fetchall()
        if clips:
            yield video_id, lift_key, clips


@dataclass(frozen=True, eq=False)
class FootageClip:
    """An unbroken run of an interaction clip's steps lifted for both fighters: the fighter's
    qpos (T, 35), the other fighter's at the same steps, the fighter's bones, its video and the
    run's first step."""

    video_id: str
    qpos: np.ndarray
    other_qpos: np.ndarray
    bones: BoneLengths
    start_step: int = 0

    @property
    def name(self) -> str:
        return f"{self.video_id[:12]}@{self.start_step}"


def footage_clips(
    con: duckdb.DuckDBPyConnection, dataset_key: str, role: str = "adversary", split: str = "train"
) -> list[FootageClip]:
    """The ``role``'s footage in dataset ``dataset_key``'s ``split``: its members' interaction
    clips there ('validation' is the last `dataset.validation_fraction` of each video, which
    training never reads), cut where a step was not lifted for both fighters (a step the
    dataset bridged is not footage); empty when there is none."""
    if role not in ROLES:
        raise ValueError(f"role must be one of {ROLES}, got {role!r}")
    other = ROLES[1 - ROLES.index(role)]
    found = []
    members = dataset_info(con, dataset_key).members
    for video_id, lift_key, clips in interaction_clips(con, members, split):
        fighters = load_motion(con, video_id, lift_key)
        if role not in fighters or other not in fighters:
            continue
        mine, theirs = fighters[role], fighters[other]
        lifted = np.intersect1d(mine.step, theirs.step)
        for start, end in clips:
            steps = lifted[(lifted >= start) & (lifted < end)]
            for run in np.split(steps, np.flatnonzero(np.diff(steps) != 1) + 1):
                if len(run):
                    found.append(
                        FootageClip(
                            video_id,
                            mine.qpos[mine.rows(run)],
                            theirs.qpos[theirs.rows(run)],
                            mine.bones,
                            int(run[0]),
                        )
                    )
    return found


def training_bones(
    con: duckdb.DuckDBPyConnection, dataset_key: str
) -> tuple[BoneLengths, BoneLengths] | None:
    """The two humanoids a run on dataset ``dataset_key`` trains (adversary, opponent): the
    fighters of the member video with the most interaction steps to learn from (the first of
    equals); None without interaction clips."""
    best, most = None, 0
    for video_id, lift_key, clips in interaction_clips(con, dataset_info(con, dataset_key).members):
        steps = sum(end - start for start, end in clips)
        if steps > most:
            best, most = (video_id, lift_key), steps
    if best is None:
        return None
    bones = load_bones(con, *best)
    return bones[ROLES[0]], bones[ROLES[1]]


@dataclass(frozen=True, eq=False)
class TrainingData:
    """What a training run reads from a dataset (its train split): the discriminators'
    transitions, the frames episodes start from (qpos and qvel of adversary and opponent at the
    same steps) and the two humanoids (`training_bones`); and the validation split's
    transitions (motion, then each agent's interaction; any may be empty), which training
    never learns from and judges its discriminators on."""

    motion: np.ndarray
    interaction: tuple[np.ndarray, np.ndarray]
    qpos: tuple[np.ndarray, np.ndarray]
    qvel: tuple[np.ndarray, np.ndarray]
    bones: tuple[BoneLengths, BoneLengths]
    held_out: tuple[np.ndarray, np.ndarray, np.ndarray]


def training_data(con: duckdb.DuckDBPyConnection, dataset_key: str) -> TrainingData:
    """Everything training needs from dataset ``dataset_key`` (its train split).

    Raises:
        UnknownDataset: no such dataset.
        BadInput: the dataset cannot be trained on (no interaction clip in its train split to
            learn from or start episodes in), naming why (`dataset_verdicts`).
    """
    info = dataset_info(con, dataset_key)
    unusable = dataset_verdicts(con)[info.dataset_key]
    if unusable is not None:
        raise BadInput(f"dataset {info.dataset_key}", f"cannot be trained on: {unusable}")
    motion = _pairs(con, dataset_key, "single", None)
    interaction = tuple(_pairs(con, dataset_key, "interaction", a) for a in (0, 1))
    frames: list[tuple[np.ndarray, ...]] = []
    for video_id, lift_key, clips in interaction_clips(con, info.members):
        fighters = load_motion(con, video_id, lift_key)
        steps = np.concatenate([np.arange(a, b) for a, b in clips])
        # Episodes start from lifted steps only: the few a clip bridged
        # (`tasks.dataset.bridging`) are not in the lift's rows.
        for role in ROLES:
            steps = steps[np.isin(steps, fighters[role].step)]
        rows = {role: fighters[role].rows(steps) for role in ROLES}
        frames.append(
            tuple(getattr(fighters[r], f)[rows[r]] for r in ROLES for f in ("qpos", "qvel"))
        )
    bones = training_bones(con, dataset_key)
    # The verdict found interaction clips in the train split, so these exist.
    assert bones is not None and min(len(x) for x in interaction) > 0, dataset_key
    q0, v0, q1, v1 = (np.concatenate([f[i] for f in frames]) for i in range(4))
    held_out = (
        _pairs(con, dataset_key, "single", None, "validation"),
        *(_pairs(con, dataset_key, "interaction", a, "validation") for a in (0, 1)),
    )
    return TrainingData(motion, interaction, (q0, q1), (v0, v1), bones, held_out)
