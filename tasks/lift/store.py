"""Reading a lift output back from DuckDB: each fighter's motion, and its cleanup series."""

from __future__ import annotations

import duckdb
import numpy as np

from models.humanoid.boxer import BoneLengths
from tasks.errors import BadInput
from tasks.lift.motion import FighterMotion
from tasks.lift.series import LiftSeries, cleanup_series


def _bone_rows(
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
    rows = _bone_rows(con, video_id, lift_key)
    return {role: BoneLengths(**lengths) for role, lengths in rows.items()}


def load_motion(
    con: duckdb.DuckDBPyConnection, video_id: str, lift_key: str
) -> dict[str, FighterMotion]:
    """Each fighter's lifted motion and bone lengths from lift output ``lift_key``; a fighter
    with no ``lift_motion`` rows is left out."""
    fighters = {}
    for role, lengths in _bone_rows(con, video_id, lift_key).items():
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
    """The cleanup series (`cleanup_series`) of lift output ``key`` of video ``video_id``;
    empty (no steps, no fighters) when the output has no motion."""
    return cleanup_series(load_motion(con, video_id, key))


def newest_lift(con: duckdb.DuckDBPyConnection, video_id: str) -> tuple[str, str] | None:
    """(lift key, ingest key) of the newest committed lift output of ``video_id`` and the ingest
    output it was computed from (through its pose output); None before any lift."""
    return con.execute(
        """
        SELECT l.key, p.upstream->>'ingest'
        FROM stage_outputs l
        JOIN stage_outputs p
          ON p.stage = 'pose' AND p.video_id = l.video_id AND p.key = l.upstream->>'pose'
        WHERE l.stage = 'lift' AND l.video_id = ?
        ORDER BY l.created_at DESC
        LIMIT 1
        """,
        [video_id],
    ).fetchone()
