"""`ringside check [--repair]`, `backup` and `restore` on results in a DuckLake catalog (a real
PostgreSQL, the `lake` fixture): a Parquet file lost from the shared folder is named with the
output its rows were, removed by `--repair` and computed again by `process`; a backup is one
snapshot of the lake, and restoring it puts those rows back, the state it replaced still
readable by time travel, into a lake or into a data directory's DuckDB file."""

from __future__ import annotations

import json
from pathlib import Path

from conftest import run_cli, stage_contents

from storage.db import connect
from storage.paths import Lake
from storage.records import OutputRecord, register_video, write_output
from tasks.ingest.store import ShotRow


def lake_cli(capsys, lake: Lake, data: Path, *argv: str) -> tuple[int, str]:
    """``ringside --results LAKE --shared DIR ARGV`` (Prefect's home in ``data``): (exit code,
    stdout and stderr)."""
    where = ["--data", str(data), "--results", str(lake), "--shared", str(lake.shared)]
    code, out, err = run_cli(capsys, *where, *argv)
    return code, out + err


def lake_rows(lake: Lake, sql: str, params: list | None = None) -> list[tuple]:
    with connect(lake, read_only=True) as con:
        return con.execute(sql, params or []).fetchall()


def parquet_files(lake: Lake, table: str) -> list[Path]:
    found = lake_rows(lake, f"SELECT data_file FROM ducklake_list_files('results', '{table}')")
    return [Path(path) for (path,) in found]


def test_a_lost_parquet_file_is_named_removed_by_repair_and_computed_again(
    lake, tmp_path, capsys, two_shot_video
):
    data = tmp_path / "data"
    process = ["process", str(two_shot_video), "--adversary", "A", "--until", "ingest"]
    code, out = lake_cli(capsys, lake, data, *process)
    assert code == 0, out
    before = stage_contents(lake)
    code, out = lake_cli(capsys, lake, data, "check")
    assert code == 0 and "no damage found" in out and "Parquet file" in out, out

    [(video_id, key)] = lake_rows(
        lake, "SELECT video_id, key FROM stage_outputs WHERE stage = 'ingest'"
    )
    # A store's insert of several rows (the two shots) may leave them in a file each.
    lost, *others = parquet_files(lake, "ingest_shots")
    lost.unlink()
    code, out = lake_cli(capsys, lake, data, "check")
    assert code == 1, out
    line = f"ingest of {video_id[:12]}, output {key[:12]}: ingest_shots: Parquet file {lost.name}"
    assert f"{line} is missing" in out, out
    assert len(out.strip().splitlines()) == 1, out

    code, out = lake_cli(capsys, lake, data, "check", "--repair")
    assert code == 0, out
    assert f"removed the damaged ingest output {key[:12]}" in out and "repaired:" in out, out
    assert "made ingest_shots anew" in out, out
    # Every row of the output went, in every table of its stage, and its record.
    for table in ("stage_outputs", "ingest_shots", "ingest_probes", "ingest_chunks"):
        assert lake_rows(lake, f"SELECT count(*) FROM {table} WHERE key = ?", [key]) == [(0,)]
    assert not any(path in parquet_files(lake, "ingest_shots") for path in others)
    code, out = lake_cli(capsys, lake, data, "check")
    assert code == 0, out

    code, out = lake_cli(capsys, lake, data, *process)
    assert code == 0, out
    assert stage_contents(lake) == before


def write_ingest(lake: Lake, key: str, shots: int) -> None:
    """A committed ingest output ``key`` of video "vid" with ``shots`` shots, as the stage's
    store writes it."""
    record = OutputRecord("ingest", "vid", key, {"k": key}, "code", {}, f"run-{key}", 0.5)
    rows = [ShotRow(i, 10 * i, 10 * i + 10, 0.5, f"thumb-{i}") for i in range(shots)]
    with connect(lake) as con:
        register_video(con, "vid", 100, "/videos/vid.mp4")
        write_output(con, record, {"ingest_shots": rows}, {"shots": float(shots)})


def shots(lake: Lake, at: int | None = None) -> list[tuple]:
    version = "" if at is None else f" AT (VERSION => {at})"
    return lake_rows(
        lake,
        f"SELECT key, count(*), sum(end_frame) FROM ingest_shots{version} GROUP BY ALL ORDER BY 1",
    )


def test_a_backup_is_one_snapshot_and_restore_puts_its_rows_back(lake, tmp_path, capsys):
    data = tmp_path / "data"
    write_ingest(lake, "k1", 2)
    write_ingest(lake, "k2", 3)
    folder = tmp_path / "backup"
    code, out = lake_cli(capsys, lake, data, "backup", str(folder))
    assert code == 0, out
    manifest = json.loads((folder / "backup.json").read_text())
    assert f"backed up {lake} at snapshot {manifest['snapshot']}" in out, out
    assert manifest["rows"]["ingest_shots"] == 5 and manifest["rows"]["videos"] == 1
    at_backup = shots(lake)
    assert shots(lake, manifest["snapshot"]) == at_backup == [("k1", 2, 30), ("k2", 3, 60)]

    # Changed since: an output rewritten, one added; a backup of that goes through too.
    write_ingest(lake, "k2", 1)
    write_ingest(lake, "k3", 4)
    changed = shots(lake)
    assert changed == [("k1", 2, 30), ("k2", 1, 10), ("k3", 4, 100)]
    again = tmp_path / "backup-of-the-change"
    code, out = lake_cli(capsys, lake, data, "backup", str(again))
    assert code == 0, out
    assert json.loads((again / "backup.json").read_text())["rows"]["ingest_shots"] == 7

    # Then a file of k3's shots damaged in place (its size kept: only reading it tells) and
    # the file of the table of videos lost, which no rerun gives back: --repair removes k3
    # and refuses the other in one line.
    damaged = Path(lake_rows(lake, "SELECT min(filename) FROM ingest_shots WHERE key = 'k3'")[0][0])
    content = bytearray(damaged.read_bytes())
    content[4:60] = bytes(56)
    damaged.write_bytes(bytes(content))
    (videos,) = parquet_files(lake, "videos")
    videos.unlink()
    code, out = lake_cli(capsys, lake, data, "check")
    assert code == 1, out
    assert (
        f"ingest of vid, output k3: ingest_shots: Parquet file {damaged.name} does not read" in out
    )
    assert f"database: videos: Parquet file {videos.name} is missing" in out, out
    code, out = lake_cli(capsys, lake, data, "check", "--repair")
    assert code == 1, out
    assert "removed the damaged ingest output k3" in out, out
    refused = [line for line in out.splitlines() if line.startswith("repair: cannot repair")]
    assert len(refused) == 1 and f"videos: Parquet file {videos.name} is missing" in refused[0]
    repaired = shots(lake)
    assert repaired == changed[:2]

    (replaced,) = lake_rows(lake, "SELECT id FROM results.current_snapshot()")[0]
    code, out = lake_cli(capsys, lake, data, "restore", str(folder))
    assert code == 0, out
    assert f"the lake as it was is its snapshot {replaced}" in out, out
    assert shots(lake) == at_backup
    assert lake_rows(lake, "SELECT video_id FROM videos") == [("vid",)]
    assert shots(lake, replaced) == repaired  # time travel reaches what was replaced
    assert lake_cli(capsys, lake, data, "check")[0] == 0

    # The lake's backup into a data directory's DuckDB file (a new, migrated one: keys and
    # fixed-size arrays), and that file's backup into the lake: the same rows.
    file_data = tmp_path / "file-data"
    code, out, err = run_cli(capsys, "--data", str(file_data), "restore", str(again))
    assert code == 0, out + err
    file_backup = tmp_path / "file-backup"
    code, out, err = run_cli(capsys, "--data", str(file_data), "backup", str(file_backup))
    assert code == 0, out + err
    with connect(file_data / "ringside.duckdb", read_only=True) as con:
        in_file = con.execute("SELECT key, count(*), sum(end_frame) FROM ingest_shots GROUP BY ALL")
        assert sorted(in_file.fetchall()) == changed
    code, out = lake_cli(capsys, lake, data, "restore", str(file_backup))
    assert code == 0, out
    assert shots(lake) == changed
