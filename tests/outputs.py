"""What a run of the per-video stages computed, compared across runs: the tests' and the
benchmarks' (which import this file directly; it has no side effects, unlike conftest)."""

from __future__ import annotations

from pathlib import Path

from storage.db import connect
from storage.paths import Lake, data_paths

# The per-stage tables whose rows a rerun must give back identically, and the metrics that are
# timings (they differ from run to run).
CONTENT = ("ingest_shots", "pose_keypoints", "lift_motion", "lift_bones", "dataset_transitions")
PER_VIDEO = ("ingest", "pose", "lift", "dataset")
TIMINGS = {("ingest", "decode_fps"), ("pose", "fps")}


def stage_contents(data: Path | Lake) -> dict:
    """What the per-video stages computed (in data directory ``data``'s DuckDB file, or the lake
    ``data``): output keys, content rows (hashed), metrics (timings left out); what a resumed or
    repaired run must give back identically, and either backend alike (rows are hashed as
    text: a lake's lists and a file's fixed-size arrays of the same values read the same)."""
    db = data if isinstance(data, Lake) else data_paths(data).db
    with connect(db, read_only=True) as con:
        found = {
            table: con.execute(
                f"SELECT video_id, key, count(*), bit_xor(hash(t::VARCHAR)) FROM {table} t "
                "GROUP BY ALL ORDER BY ALL"
            ).fetchall()
            for table in CONTENT
        }
        found["outputs"] = con.execute(
            "SELECT stage, video_id, key FROM stage_outputs "
            f"WHERE stage IN {PER_VIDEO} ORDER BY ALL"
        ).fetchall()
        found["metrics"] = [
            row
            for row in con.execute(
                "SELECT stage, video_id, key, name, value FROM stage_metrics "
                f"WHERE stage IN {PER_VIDEO} ORDER BY ALL"
            ).fetchall()
            if (row[0], row[3]) not in TIMINGS
        ]
    return found


def differences(found: dict, expected: dict) -> list[str]:
    """What differs between two `stage_contents`: table names, and each differing metric."""
    differs = [part for part in expected if part != "metrics" and found[part] != expected[part]]
    metrics = {row[:4]: row[4] for row in found["metrics"]}
    wanted = {row[:4]: row[4] for row in expected["metrics"]}
    differs += [
        f"{name}: {metrics.get(name)} != {wanted.get(name)}"
        for name in sorted(set(metrics) | set(wanted))
        if metrics.get(name) != wanted.get(name)
    ]
    return differs
