"""`ringside check [--repair]` on real damage: flipped bytes in a table's blocks, a truncated and
an emptied database, deleted artifacts, a path outside the store; then `process` gives back the
same results."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import copy_data, process_argv, query, render_page, run_cli, stage_contents
from tiny import TINY_EVALUATE_FLAGS, TINY_PIPELINE_FLAGS

from storage.artifacts import NotAnArtifact, artifact_path, put_bytes, read_bytes
from storage.check import remove_stale_temporaries, stale_temporaries
from storage.db import connect
from storage.paths import data_paths

BLOCK_SIZE, HEADER = 262144, 3 * 4096  # DuckDB's default block size and file header


def checkpointed_copy(source, target):
    """A data directory of the test's own whose database has no write-ahead log (the blocks
    are all in the file, where the test damages them)."""
    data = copy_data(source, target)
    with connect(data_paths(data).db) as con:
        con.execute("CHECKPOINT")
    return data


def flip_block(db, table: str) -> int:
    """Overwrite 64 bytes inside the block holding ``table``'s largest column segment; the
    block's file offset."""
    with connect(db, read_only=True) as con:
        block, offset = con.execute(
            f"SELECT block_id, block_offset FROM pragma_storage_info('{table}') "
            "WHERE block_id >= 0 ORDER BY count DESC, block_offset DESC LIMIT 1"
        ).fetchone()
    where = HEADER + block * BLOCK_SIZE + offset + 16
    with db.open("r+b") as file:
        file.seek(where)
        original = file.read(64)
        file.seek(where)
        file.write(bytes(b ^ 0xFF for b in original))
    return HEADER + block * BLOCK_SIZE


def check(capsys, data, *more):
    code, out, err = run_cli(capsys, "--data", str(data), "check", *more)
    return code, out + err


def test_damaged_blocks_and_lost_files_are_named_then_repaired(
    tmp_path, capsys, sample_run, sample_video
):
    data = checkpointed_copy(sample_run, tmp_path / "data")
    paths = data_paths(data)
    before = stage_contents(data)
    assert check(capsys, data)[0] == 0

    flip_block(paths.db, "pose_keypoints")
    video = query(data, "SELECT artifact FROM lift_media WHERE kind = 'video'")[0][0]
    artifact_path(paths.artifacts, video).unlink()
    stale = paths.artifacts / "ab" / ".tmp-left-by-a-kill"
    stale.parent.mkdir(exist_ok=True)
    stale.write_bytes(b"half a checkpoint")
    os.utime(stale, (0, 0))

    code, out = check(capsys, data)
    assert code == 1
    pose_key = query(data, "SELECT key FROM stage_outputs WHERE stage = 'pose'")[0][0]
    lift_key = query(data, "SELECT key FROM stage_outputs WHERE stage = 'lift'")[0][0]
    assert f"pose of {before['outputs'][0][1][:12]}, output {pose_key[:12]}" in out, out
    assert "rows of pose_keypoints are damaged: a damaged block" in out
    assert f"output {lift_key[:12]}: lift_media: artifact {video[:12]}… is missing" in out
    assert ".tmp-left-by-a-kill is left over from an interrupted write" in out
    assert len(out.strip().splitlines()) <= 6, out
    code, out = check(capsys, data, "--repair")
    assert code == 0, out
    assert "repaired: `ringside process`" in out and not stale.exists()
    assert sorted(p.name for p in data.glob("ringside.duckdb.damaged-*"))
    assert check(capsys, data)[0] == 0
    states = json.loads(run_cli(capsys, "--data", str(data), "status", "--json")[1])
    # The damaged output's video (the shared run may hold other tests' videos and reruns).
    video_id = before["outputs"][0][1]
    assert {(r["video_id"], r["stage"]): r["state"] for r in states}[video_id, "pose"] == (
        "missing"
    ), states

    argv = process_argv(data, sample_video, "--ingest-chunk-frames", "30")
    assert run_cli(capsys, *argv)[0] == 0
    assert stage_contents(data) == before

    # A chunk file that Prefect's cache still names is gone: tracked again, not an error (the
    # new file has another name: a chunk's .npz holds the time it was written).
    chunk = next(p for p in paths.artifacts.rglob("*.npz"))
    chunk.unlink()
    rerun = ["--data", str(data), "rerun", "pose", "--video", before["outputs"][0][1][:12]]
    code, _, err = run_cli(capsys, *rerun, "--until", "pose", "--ingest-chunk-frames", "30")
    assert code == 0, err
    assert stage_contents(data) == before


def test_truncated_artifacts_are_quarantined_then_recomputed(
    tmp_path, capsys, sample_run, sample_dataset, sample_video
):
    """A checkpoint, a bouts .npz, a review video and a pose chunk's .npz (named by Prefect's
    cache, not by a row) cut to half their bytes: `check` names them, `--repair` moves them
    aside, `process` writes them anew (the same names: a write checks what is there), and
    `check`, `evaluate` and `export` work again."""
    data = copy_data(sample_run, tmp_path / "data")
    paths = data_paths(data)
    argv = process_argv(data, sample_video, "--ingest-chunk-frames", "30", *TINY_PIPELINE_FLAGS)
    argv[argv.index("--until") + 1] = "evaluate"
    code, out, _ = run_cli(capsys, *argv, "--json")
    assert code == 0
    # This run's outputs (the shared run may hold other tests' runs and reruns).
    keys = {summary["stage"]: summary["key"] for summary in json.loads(out)}
    run = keys["train"]
    named = {
        "checkpoint": (
            "SELECT artifact FROM train_checkpoints WHERE key = ? ORDER BY iteration DESC LIMIT 1",
            [run],
        ),
        "bouts": (
            "SELECT artifact FROM evaluate_artifacts WHERE key = ? AND artifact LIKE '%.npz' "
            "LIMIT 1",
            [keys["evaluate"]],
        ),
        "video": (
            "SELECT artifact FROM lift_media WHERE key = ? AND kind = 'video'",
            [keys["lift"]],
        ),
    }
    names = {what: query(data, *sql)[0][0] for what, sql in named.items()}
    # A pose chunk's file: an .npz no table names (the shared run may hold other tests' outputs).
    tables = query(data, "SELECT table_name FROM duckdb_columns() WHERE column_name = 'artifact'")
    rows = {n for (table,) in tables for (n,) in query(data, f"SELECT artifact FROM {table}")}
    chunk = next(p for p in sorted(paths.artifacts.rglob("*.npz")) if p.name not in rows)
    names["chunk"] = chunk.name
    for name in names.values():
        path = artifact_path(paths.artifacts, name)
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])

    code, out = check(capsys, data)
    assert code == 1, out
    for name in names.values():
        assert f"artifact {name[:12]}… is corrupt" in out, out
    code, out = check(capsys, data, "--repair")
    assert code == 0, out
    aside = sorted(p.name.split(".")[0] for p in (paths.artifacts / "quarantine").iterdir())
    assert aside == sorted(name[:64] for name in names.values())

    assert run_cli(capsys, *argv)[0] == 0
    assert check(capsys, data)[0] == 0
    for what in ("checkpoint", "bouts", "video"):
        assert query(data, *named[what])[0][0] == names[what], what
        assert read_bytes(paths.artifacts, names[what])
    evaluate = ["--data", str(data), "evaluate", "--run", run[:12], *TINY_EVALUATE_FLAGS]
    code, _, err = run_cli(capsys, *evaluate)
    assert code == 0, err
    code, _, err = run_cli(capsys, "--data", str(data), "export", "--run", run[:12])
    assert code == 0, err


def test_a_write_over_a_corrupt_file_of_the_same_name_replaces_it(tmp_path):
    name = put_bytes(tmp_path, b"a checkpoint", ".pt")
    artifact_path(tmp_path, name).write_bytes(b"a check")
    assert put_bytes(tmp_path, b"a checkpoint", ".pt") == name
    assert read_bytes(tmp_path, name) == b"a checkpoint"
    (aside,) = (tmp_path / "quarantine").iterdir()
    assert aside.read_bytes() == b"a check" and aside.name.startswith(name + ".")


@pytest.mark.parametrize("how", ["truncated", "emptied"])
def test_a_truncated_or_emptied_database_is_named_and_repaired(
    tmp_path, capsys, sample_run, how, monkeypatch
):
    data = checkpointed_copy(sample_run, tmp_path / "data")
    db = data_paths(data).db
    with db.open("r+b") as file:
        file.truncate(db.stat().st_size // 2 if how == "truncated" else 0)

    code, out = check(capsys, data)
    assert code == 1 and out.strip(), out
    if how == "emptied":
        assert "cannot be opened" in out and len(out.strip().splitlines()) == 1, out
        code, _, err = run_cli(capsys, "--data", str(data), "status")
        assert code == 1 and len(err.strip().splitlines()) == 1, err
        assert f"the database {db} is damaged" in err and "ringside check --repair" in err
        from streamlit.testing.v1 import AppTest

        monkeypatch.setenv("RINGSIDE_DATA", str(data))
        app = AppTest.from_function(render_page, args=("overview",), default_timeout=60).run()
        assert not app.exception, app.exception
        assert any("is damaged" in e.value for e in app.error), app.error
    code, out = check(capsys, data, "--repair")
    assert code == 0, out
    # Half the sample's file holds none of DuckDB's catalogue: as with an emptied file nothing
    # reads back, and a new, empty database takes its place (where `process` starts on a new
    # machine; the damaged-blocks test above shows `process` giving back what was left out).
    assert "a new, empty database replaces it" in out
    assert query(data, "SELECT count(*) FROM stage_outputs") == [(0,)]
    assert run_cli(capsys, "--data", str(data), "status", "--json")[1].strip() == "[]"


def test_a_path_outside_the_store_is_refused_everywhere(tmp_path, capsys, sample_run, monkeypatch):
    from streamlit.testing.v1 import AppTest

    data = copy_data(sample_run, tmp_path / "data")
    outside = str(tmp_path / "secret.txt")
    (tmp_path / "secret.txt").write_text("not for the dashboard")
    with connect(data_paths(data).db) as con:
        con.execute("UPDATE lift_media SET artifact = ? WHERE kind = 'video'", [outside])

    with pytest.raises(NotAnArtifact):
        read_bytes(data_paths(data).artifacts, outside)
    code, out = check(capsys, data)
    assert code == 1 and f"names {outside!r}, a path outside the artifact store" in out, out

    monkeypatch.setenv("RINGSIDE_DATA", str(data))
    app = AppTest.from_function(render_page, args=("lift",), default_timeout=60).run()
    assert not app.exception, app.exception
    assert any("not an artifact name" in e.value for e in app.error), app.error
    assert not app.get("video")


def test_check_json_lists_each_problem(tmp_path, capsys, sample_run):
    data = checkpointed_copy(sample_run, tmp_path / "data")
    overlay = query(data, "SELECT artifact FROM pose_media WHERE kind = 'overlay'")[0][0]
    artifact_path(data_paths(data).artifacts, overlay).unlink()
    code, out = check(capsys, data, "--json")
    assert code == 1
    found = json.loads(out)
    assert [(p["stage"], p["what"]) for p in found["problems"]] == [
        ("pose", f"pose_media: artifact {overlay[:12]}… is missing")
    ]
    assert found["left"] == found["problems"] and found["repaired"] == []


def test_a_backup_restores_an_emptied_database(tmp_path, capsys, sample_run):
    data = checkpointed_copy(sample_run, tmp_path / "data")
    before = stage_contents(data)
    folder = tmp_path / "backup"
    code, out, err = run_cli(capsys, "--data", str(data), "backup", str(folder))
    assert code == 0 and "backed up" in out, err

    data_paths(data).db.write_bytes(b"")
    restore = ["--data", str(data), "restore", str(folder)]
    code, out, err = run_cli(capsys, *restore)
    assert code == 0, out + err
    assert stage_contents(data) == before and check(capsys, data)[0] == 0
    assert [p.stat().st_size for p in data.glob("ringside.duckdb.replaced-*")] == [0]

    # A backup whose bytes changed is refused; the database stays as it was.
    (folder / "ringside.duckdb").write_bytes(b"not a database")
    code, _, err = run_cli(capsys, *restore)
    assert code == 2 and "changed since the backup was taken" in err, err
    assert len(err.strip().splitlines()) == 1 and stage_contents(data) == before


def test_a_temporary_file_is_stale_once_its_writer_is_gone(tmp_path):
    exited = subprocess.Popen(["true"])
    exited.wait()
    folder = tmp_path / "artifacts" / "ab"
    folder.mkdir(parents=True)
    mine = folder / f".tmp-{os.getpid()}-abc"  # being written by this (live) process
    dead = folder / f".tmp-{exited.pid}-def"
    for path in (mine, dead):
        path.write_bytes(b"half")
    assert stale_temporaries(tmp_path / "artifacts") == [dead]


def test_a_scratch_folder_of_a_killed_process_is_removed_by_the_next_command(tmp_path):
    """A stage's scratch folder in the system's temporary directory (the lift's video, the
    overlay's frames) outlives a SIGKILL; the next `process` removes it, not a live one's."""
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    code = (
        "import sys, time; from storage.files import scratch_dir\n"
        "with scratch_dir('lift') as tmp:\n    print(tmp, flush=True); time.sleep(60)"
    )
    env = {**os.environ, "TMPDIR": str(scratch), "PYTHONPATH": str(Path(__file__).parents[1])}
    child = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, env=env, text=True
    )
    killed = Path(child.stdout.readline().strip())
    child.kill()
    child.wait()
    child.stdout.close()
    alive = scratch / f"ringside-overlay-{os.getpid()}-abc"
    alive.mkdir()
    assert killed.is_dir() and killed.parent == scratch
    removed = remove_stale_temporaries(tmp_path / "artifacts", scratch_root=scratch)
    assert removed == [killed] and not killed.exists() and alive.is_dir()


def test_a_damaged_prefect_database_is_one_line_named_by_check_and_set_aside(
    two_shot_video, tmp_path, capsys, monkeypatch
):
    """Prefect's own database (its run history) damaged (here overwritten; 64-byte flips gave
    "database disk image is malformed" the same way): every flow command printed a 20-line
    traceback ending in "did not start within 120 s" after its server died in 4 s.
    Now the command says so in one line, `check` names the file, `--repair` sets it aside and
    the next command starts Prefect anew."""
    home = tmp_path / "prefect-home"
    home.mkdir()
    prefect_db = home / "prefect.db"  # overwritten: SQLite's "file is not a database"
    prefect_db.write_bytes(bytes(range(256)) * 256)
    monkeypatch.setenv("PREFECT_HOME", str(home))
    data = tmp_path / "data"
    code, out, err = run_cli(capsys, *process_argv(data, two_shot_video, until="ingest"))
    assert code == 1 and out == ""
    assert err.count("\n") == 1 and f"Prefect's database {prefect_db} is damaged" in err, err
    assert "`ringside check --repair` sets it aside" in err
    assert not (data / "ringside.duckdb").exists()  # the command stopped before it made one
    code, out, _ = run_cli(capsys, "--data", str(data), "check")
    assert code == 1 and f"prefect: Prefect's database {prefect_db} is damaged" in out
    code, out, _ = run_cli(capsys, "--data", str(data), "check", "--repair")
    assert code == 0 and "set Prefect's database aside as" in out
    assert not prefect_db.exists() and list(home.glob("prefect.db.damaged-*"))
    code, _, err = run_cli(capsys, *process_argv(data, two_shot_video, until="ingest"))
    assert code == 0, err
    code, out, _ = run_cli(capsys, "--data", str(data), "check")
    assert code == 0 and "no damage found" in out
