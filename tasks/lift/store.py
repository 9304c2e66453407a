"""Reading a lift output back from DuckDB: each fighter's motion, and its cleanup measures."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

import duckdb
import numpy as np

from models.humanoid.boxer import BoneLengths
from models.humanoid.motion import (
    RATE,
    FighterMotion,
    FighterSeries,
    LiftSeries,
    fighter_distance,
)
from tasks.errors import BadInput


@dataclass(frozen=True)
class CameraRow:
    """A ``lift_cameras`` row: one shot's camera (K, R row-major, t; x_cam = R x_world + t)."""

    shot: int
    source: str  # "calibration" or "fov"
    K: list[float]
    R: list[float]
    t: list[float]
    height_m: float
    pitch_deg: float


@dataclass(frozen=True)
class BoneRow:
    """A ``lift_bones`` row: one fighter's bone length."""

    role: str
    bone: str
    length_m: float


@dataclass(frozen=True)
class MediaRow:
    """A ``lift_media`` row: a review file of the output in the artifact store."""

    kind: str
    artifact: str


def bone_rows(bones: Mapping[str, BoneLengths]) -> list[BoneRow]:
    """The ``lift_bones`` rows of each fighter's bone lengths."""
    return [
        BoneRow(role, name, float(value))
        for role, lengths in bones.items()
        for name, value in dataclasses.asdict(lengths).items()
    ]


def _stored_bones(
    con: duckdb.DuckDBPyConnection, video_id: str, lift_key: str
) -> dict[str, dict[str, float]]:
    bones: dict[str, dict[str, float]] = {}
    for role, bone, length in con.execute(
        "SELECT role, bone, length_m FROM lift_bones WHERE key = ? AND video_id = ?",
        [lift_key, video_id],
    ).fetchall():
        bones.setdefault(role, {})[bone] = length
    return bones


def load_bones(
    con: duckdb.DuckDBPyConnection, video_id: str, lift_key: str
) -> dict[str, BoneLengths]:
    """Each fighter's bone lengths from lift output ``lift_key``, by role."""
    rows = _stored_bones(con, video_id, lift_key)
    return {role: BoneLengths(**lengths) for role, lengths in rows.items()}


def load_motion(
    con: duckdb.DuckDBPyConnection, video_id: str, lift_key: str
) -> dict[str, FighterMotion]:
    """Each fighter's lifted motion and bone lengths from lift output ``lift_key``; a fighter
    with no ``lift_motion`` rows is left out."""
    fighters = {}
    for role, lengths in _stored_bones(con, video_id, lift_key).items():
        columns = con.execute(
            "SELECT step, qpos, qvel, joints, contact_left, contact_right FROM lift_motion "
            "WHERE key = ? AND video_id = ? AND role = ? ORDER BY step",
            [lift_key, video_id, role],
        ).fetchnumpy()
        if len(columns["step"]) == 0:
            continue
        qpos = np.stack(columns["qpos"]).astype(np.float64)
        qvel = np.stack(columns["qvel"]).astype(np.float64)
        bad = ~(np.isfinite(qpos).all(1) & np.isfinite(qvel).all(1))
        if bad.any():
            steps = columns["step"][bad]
            raise BadInput(
                f"lift_motion of video {video_id[:12]} (lift key {lift_key[:12]})",
                f"the {role}'s qpos/qvel is not finite at {len(steps)} steps from step "
                f"{steps[0]}; the rows are damaged: rerun the lift "
                f"(`ringside rerun lift --video {video_id[:12]}`)",
            )
        fighters[role] = FighterMotion(
            step=np.asarray(columns["step"], dtype=np.int64),
            qpos=qpos,
            qvel=qvel,
            joints=np.stack(columns["joints"]).astype(np.float64).reshape(-1, 33, 3),
            contacts=np.stack([columns["contact_left"], columns["contact_right"]], axis=1),
            bones=BoneLengths(**lengths),
        )
    return fighters


def lift_series(con: duckdb.DuckDBPyConnection, key: str, video_id: str) -> LiftSeries:
    """The cleanup measures the lift stored with output ``key`` of video ``video_id``
    (`tasks.lift.series.cleanup_series`) on the 30 Hz grid; empty (no steps, no fighters) when
    the output has no motion."""
    rows = con.execute(
        "SELECT role, step, qpos[1] AS x, qpos[2] AS y, floor_penetration_m, slide_left_m_s, "
        "slide_right_m_s FROM lift_motion WHERE key = ? AND video_id = ? ORDER BY role, step",
        [key, video_id],
    ).fetchnumpy()
    roles = np.asarray(rows["role"])
    steps = int(rows["step"].max()) + 1 if len(roles) else 0
    # On the grid, NaN where a fighter has no row; NULL (an output made before the measures were
    # stored) reads as NaN too.
    grid: dict[str, dict[str, np.ndarray]] = {}
    for role in np.unique(roles):
        mine = roles == role
        grid[role] = {}
        for name in ("x", "y", "floor_penetration_m", "slide_left_m_s", "slide_right_m_s"):
            values = grid[role][name] = np.full(steps, np.nan)
            values[rows["step"][mine]] = np.ma.filled(
                np.ma.asarray(rows[name][mine], float), np.nan
            )
    fighters = {
        role: FighterSeries(
            contact_slide_m_s=np.stack([g["slide_left_m_s"], g["slide_right_m_s"]], axis=1),
            floor_penetration_m=g["floor_penetration_m"],
        )
        for role, g in grid.items()
    }
    distance = np.full(steps, np.nan)
    if len(grid) == 2:
        a, b = (np.stack([g["x"], g["y"]], axis=1) for g in grid.values())
        distance = fighter_distance(a, b)  # NaN where either is missing
    return LiftSeries(
        time_s=np.arange(steps) / RATE, fighters=fighters, fighter_distance_m=distance
    )


def newest_lift(con: duckdb.DuckDBPyConnection, video_id: str) -> tuple[str, str] | None:
    """(lift key, ingest key) of the newest committed lift output of ``video_id`` and the ingest
    output it was computed from (through its pose output); None before any lift."""
    return con.execute(
        """
        SELECT l.key, p.upstream->>'ingest'
        FROM stage_outputs l
        JOIN stage_outputs p
          ON p.stage = 'pose' AND p.video_id = l.video_id AND p.key = (l.upstream->>'pose')
        WHERE l.stage = 'lift' AND l.video_id = ?
        ORDER BY l.created_at DESC
        LIMIT 1
        """,
        [video_id],
    ).fetchone()


def lift_media(con: duckdb.DuckDBPyConnection, key: str, video_id: str) -> dict[str, str]:
    """Kind -> artifact of lift output ``key``'s review media (kind 'video': both humanoids)."""
    return dict(
        con.execute(
            "SELECT kind, artifact FROM lift_media WHERE key = ? AND video_id = ?", [key, video_id]
        ).fetchall()
    )
