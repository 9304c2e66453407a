from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import duckdb
import numpy as np
import pytest

from storage.artifacts import artifact_path, put_bytes, read_bytes
from storage.db import DatabaseBusy, connect, migrations, transaction
from storage.keys import code_version, stable_json, stage_key
from storage.records import (
    OutputRecord,
    insert_columns,
    latest_metrics,
    latest_runs,
    record_run,
    register_video,
    write_output,
)
from tasks.ingest.store import ChunkRow, ShotRow


def record(key: str = "k1", run_id: str = "run-1") -> OutputRecord:
    return OutputRecord("ingest", "vid", key, {"a": 1}, "code", {"video": "vid"}, run_id, 0.5)


def chunk_rows(n: int) -> list[ChunkRow]:
    return [ChunkRow(i, 0, i * 10, i * 10 + 10) for i in range(n)]


def test_migrations_apply_once(tmp_path: Path):
    db = tmp_path / "r.duckdb"
    with connect(db) as con:
        versions = [r[0] for r in con.execute("SELECT version FROM schema_migrations").fetchall()]
    assert versions == [v for v, _, _ in migrations()]
    with connect(db) as con:
        again = con.execute("SELECT count(*) FROM schema_migrations").fetchone()[0]
    assert again == len(versions)


def test_a_reader_of_a_database_left_unmigrated_migrates_it_first(tmp_path: Path):
    """A writer killed between creating the file and committing the migrations leaves a database
    without tables (seen in `make test`: the next run's read-only look for a cached output
    failed on "Table with name stage_outputs does not exist"). Half-migrated, the same."""
    from tasks.runner import committed

    empty = tmp_path / "empty.duckdb"
    duckdb.connect(str(empty)).close()
    assert committed(empty, "ingest", "vid", "k1") is None
    with connect(empty, read_only=True) as con:
        assert con.execute("SELECT count(*) FROM stage_outputs").fetchone() == (0,)
    half = tmp_path / "half.duckdb"
    with duckdb.connect(str(half)) as con:
        con.execute(
            "CREATE TABLE schema_migrations (version INTEGER PRIMARY KEY, name VARCHAR NOT NULL, "
            "applied_at TIMESTAMP NOT NULL)"
        )
        version, name, sql = migrations()[0]
        con.execute(sql)
        con.execute("INSERT INTO schema_migrations VALUES (?, ?, now())", [version, name])
    with connect(half, read_only=True) as con:
        versions = [r[0] for r in con.execute("SELECT version FROM schema_migrations").fetchall()]
    assert sorted(versions) == [v for v, _, _ in migrations()]


def test_rewrite_replaces_rows_and_metrics(tmp_path: Path):
    db = tmp_path / "r.duckdb"
    with connect(db) as con:
        write_output(con, record(), {"ingest_chunks": chunk_rows(3)}, {"chunks": 3.0})
        write_output(con, record(run_id="run-2"), {"ingest_chunks": chunk_rows(2)}, {"chunks": 2.0})
        assert con.execute("SELECT count(*) FROM ingest_chunks").fetchone()[0] == 2
        assert con.execute("SELECT count(*) FROM stage_outputs").fetchone()[0] == 1
        assert latest_metrics(con) == [
            {"video_id": "vid", "stage": "ingest", "key": "k1", "name": "chunks", "value": 2.0}
        ]
        assert [r["state"] for r in latest_runs(con)] == ["done"]


def test_failed_write_keeps_previous_output(tmp_path: Path):
    db = tmp_path / "r.duckdb"
    with connect(db) as con:
        write_output(con, record(), {"ingest_chunks": chunk_rows(3)}, {"chunks": 3.0})
        broken = {"ingest_chunks": chunk_rows(1), "ingest_shots": [ShotRow(0, 0, 10, None, None)]}
        with pytest.raises(duckdb.Error):
            write_output(con, record(run_id="run-2"), broken, {"chunks": 1.0})
        assert con.execute("SELECT count(*) FROM ingest_chunks").fetchone()[0] == 3
        run = con.execute("SELECT run_id FROM stage_outputs").fetchall()
        assert run == [("run-1",)]


def test_a_running_stage_reads_as_interrupted_once_its_process_has_gone(tmp_path: Path):
    with connect(tmp_path / "r.duckdb") as con:
        register_video(con, "vid", 1, "/v.mp4")
        record_run(con, "run-1", "vid", "pose", "k1", "running")
        assert [(r["state"], r["key"]) for r in latest_runs(con)] == [("running", "k1")]
        # The same note from a process that has exited since.
        gone = subprocess.run(
            [sys.executable, "-c", "import os; print(os.getpid())"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        con.execute("UPDATE stage_runs SET worker = split_part(worker, ':', 1) || ':' || ?", [gone])
        (run,) = latest_runs(con)
        assert run["state"] == "interrupted" and "killed or crashed" in run["error"]
        write_output(con, record(), {}, {"chunks": 1.0})
        con.execute("UPDATE stage_outputs SET stage = 'pose'")
        con.execute("UPDATE stage_runs SET stage = 'pose' WHERE state = 'done'")
        assert [r["state"] for r in latest_runs(con)] == ["done"]


def test_non_finite_metric_is_refused(tmp_path: Path):
    with connect(tmp_path / "r.duckdb") as con, pytest.raises(ValueError, match="finite"):
        write_output(con, record(), {}, {"fps": float("nan")})


def test_register_video_twice_is_one_row(tmp_path: Path):
    with connect(tmp_path / "r.duckdb") as con:
        register_video(con, "vid", 10, "/a.mp4")
        register_video(con, "vid", 10, "/a.mp4")
        register_video(con, "vid", 10, "/b.mp4")
        assert con.execute("SELECT count(*) FROM videos").fetchone()[0] == 1
        assert con.execute("SELECT count(*) FROM video_files").fetchone()[0] == 2


def test_busy_database_waits_then_names_the_file(tmp_path: Path):
    db = tmp_path / "r.duckdb"
    with connect(db):
        pass
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            textwrap.dedent(f"""
            import duckdb, sys, time
            con = duckdb.connect({str(db)!r})
            print("held", flush=True)
            time.sleep(30)
        """),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(DatabaseBusy, match=str(db)), connect(db, wait_s=0.5):
            pass
    finally:
        holder.kill()
        holder.wait()
    with connect(db, wait_s=5):
        pass


def test_read_only_connect_needs_a_database(tmp_path: Path):
    with (
        pytest.raises(FileNotFoundError, match="no database yet"),
        connect(tmp_path / "none.duckdb", read_only=True),
    ):
        pass


def test_artifacts_are_content_addressed(tmp_path: Path):
    a = put_bytes(tmp_path, b"png bytes", ".png")
    assert put_bytes(tmp_path, b"png bytes", ".png") == a
    assert a.endswith(".png") and len(a) == 64 + 4
    assert read_bytes(tmp_path, a) == b"png bytes"
    artifact_path(tmp_path, a).write_bytes(b"tampered")
    with pytest.raises(ValueError, match="corrupt"):
        read_bytes(tmp_path, a)
    assert not list(tmp_path.rglob(".tmp-*"))


def test_stage_keys_follow_config_code_and_upstream():
    base = stage_key("ingest", {"a": 1, "b": 2}, "c1", {"video": "v"})
    assert stage_key("ingest", {"b": 2, "a": 1}, "c1", {"video": "v"}) == base
    assert stage_key("ingest", {"a": 1, "b": 3}, "c1", {"video": "v"}) != base
    assert stage_key("ingest", {"a": 1, "b": 2}, "c2", {"video": "v"}) != base
    assert stage_key("ingest", {"a": 1, "b": 2}, "c1", {"video": "w"}) != base
    assert stable_json({"b": [1, (2, 3)], "a": None}) == '{"a":null,"b":[1,[2,3]]}'


def test_code_version_hashes_the_stage_sources():
    assert code_version("tasks.ingest") == code_version("tasks.ingest")
    assert code_version("tasks.ingest") != code_version("storage")
    # A single module hashes that file alone, not its package.
    assert code_version("models.arena.mjcf") != code_version("models.arena")
    assert code_version("models.arena.mjcf") == code_version("models.arena.mjcf")


def test_process_killed_inside_a_transaction_leaves_the_old_output(tmp_path: Path):
    db = tmp_path / "r.duckdb"
    with connect(db) as con:
        write_output(con, record(), {"ingest_chunks": chunk_rows(3)}, {"chunks": 3.0})
    writer = subprocess.Popen(
        [
            sys.executable,
            "-c",
            textwrap.dedent(f"""
            import time, duckdb
            con = duckdb.connect({str(db)!r})
            con.begin()
            con.execute("DELETE FROM ingest_chunks")
            con.execute("INSERT INTO ingest_chunks VALUES ('k2', 'vid', 0, 0, 0, 5)")
            print("written", flush=True)
            time.sleep(60)
        """),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert writer.stdout.readline().strip() == "written"
    finally:
        writer.kill()
        writer.wait()
    with connect(db, read_only=True) as con:
        keys = con.execute("SELECT DISTINCT key FROM ingest_chunks").fetchall()
        assert keys == [("k1",)]
        assert con.execute("SELECT count(*) FROM ingest_chunks").fetchone()[0] == 3


class _Stopped(BaseException):
    """What a signal handler raises (as Prefect's does on SIGTERM)."""


def test_a_query_a_signal_stops_is_rolled_back_at_once(tmp_path: Path):
    """Before, the rollback waited for DuckDB's threads to finish the interrupted query: over
    70 s, about one time in four (so eight tries)."""
    fired: list[float] = []

    def stop(*_):
        fired.append(time.monotonic())
        raise _Stopped

    previous = signal.signal(signal.SIGUSR2, stop)
    try:
        with connect(tmp_path / "r.duckdb") as con:
            con.execute("CREATE TABLE t (a INTEGER)")
            for k in range(8):
                timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGUSR2))
                timer.start()
                with pytest.raises((_Stopped, RuntimeError)), transaction(con):
                    con.execute("INSERT INTO t VALUES (1)")
                    con.execute("SELECT count(*) FROM range(100000000000)").fetchall()
                # Stopped, rolled back and raised within a second of the signal.
                assert time.monotonic() - fired[k] < 1.0, k
                timer.join()
                assert con.execute("SELECT count(*) FROM t").fetchone() == (0,)
    finally:
        signal.signal(signal.SIGUSR2, previous)


def test_columns_insert_in_one_statement(tmp_path: Path):
    frames = np.arange(5, dtype=np.int64)
    with connect(tmp_path / "r.duckdb") as con:
        con.execute("CREATE TABLE t (key VARCHAR, video_id VARCHAR, frame INTEGER, x FLOAT[3])")
        x = np.arange(15, dtype=np.float32).reshape(5, 3)
        write_output(con, record(), {"t": {"frame": frames, "x": x}}, {})
        got = con.execute("SELECT key, video_id, frame, x FROM t ORDER BY frame").fetchall()
        assert got[4] == ("k1", "vid", 4, (12.0, 13.0, 14.0))
        with pytest.raises(ValueError, match="differ in length"):
            write_output(con, record(), {"t": {"frame": frames, "x": x[:2]}}, {})
        with pytest.raises(ValueError, match="no columns"):
            write_output(con, record(), {"t": {"nope": frames}}, {})
        assert con.execute("SELECT count(*) FROM t").fetchone()[0] == 5


def test_insert_columns_keeps_nan_and_null_apart(tmp_path):
    """NaN in float columns and arrays comes back as NaN; a missing row of an array is NULL."""
    with connect(tmp_path / "t.duckdb") as con:
        con.execute(
            "CREATE TABLE t (key VARCHAR, video_id VARCHAR, n INTEGER, x DOUBLE, "
            "a FLOAT[3], o FLOAT[2])"
        )
        opt = np.empty(2, dtype=object)
        opt[:] = [None, np.array([1.0, 2.0], np.float32)]
        insert_columns(
            con,
            "t",
            "k",
            "v",
            {
                "n": np.array([1, 2]),
                "x": np.array([np.nan, 2.5]),
                "a": np.array([[1, np.nan, 3], [4, 5, 6]], np.float32),
                "o": opt,
            },
        )
        rows = con.execute("SELECT key, n, x, a, o FROM t ORDER BY n").fetchall()
    assert rows[0][0] == "k" and math.isnan(rows[0][2]) and rows[1][2] == 2.5
    assert rows[0][3][0] == 1 and math.isnan(rows[0][3][1]) and rows[1][3] == (4, 5, 6)
    assert rows[0][4] is None and rows[1][4] == (1, 2)


def test_a_file_of_a_newer_duckdb_is_refused_in_one_line(tmp_path: Path, capsys):
    # A data directory of the Ringside that pinned DuckDB 2.0 (storage version 999): made here
    # by stamping 999 into a 1.4.4 file's main header, its checksum made again.
    from conftest import run_cli

    from storage.blocks import checksums

    data = tmp_path / "data"
    db = data / "ringside.duckdb"
    with connect(db):
        pass
    header = bytearray(db.read_bytes()[:4096])
    header[12:20] = (999).to_bytes(8, "little")
    words = np.frombuffer(bytes(header[8:]), dtype="<u8").reshape(1, -1)
    header[:8] = int(checksums(words)[0]).to_bytes(8, "little")
    with db.open("r+b") as out:
        out.write(header)
    code, _, err = run_cli(capsys, "--data", str(data), "status")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "written by a newer DuckDB (storage version 999)" in err and "EXPORT DATABASE" in err
