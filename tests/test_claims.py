"""One computation per stage output at a time: two commands on one video, or on one dataset's
training, at the same moment compute each output once; the other waits and reuses it. A claim
whose process was killed is taken over."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

from conftest import copy_data, process_argv, query
from tiny import TINY_TRAIN_FLAGS

from storage.claims import claimed, take_claim
from storage.db import connect
from storage.records import this_worker

REPO = Path(__file__).resolve().parent.parent


def ringside(*argv: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "flows.cli", *argv],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def together(*commands: list[str]) -> list[tuple[int, str, str]]:
    """Start the commands at once; (exit code, stdout, stderr) of each."""
    started = [ringside(*argv) for argv in commands]
    return [(p.wait(timeout=900), *p.communicate()) for p in started]


def computed(data: Path) -> dict[str, list[tuple[str, int]]]:
    """Per stage, how many runs computed an output ('done') and how many reused it
    ('cached')."""
    found: dict[str, list[tuple[str, int]]] = {}
    for stage, state, count in query(
        data,
        "SELECT stage, state, count(*) FROM stage_runs WHERE state IN ('done', 'cached') "
        "GROUP BY ALL ORDER BY ALL",
    ):
        found.setdefault(stage, []).append((state, count))
    return found


def test_two_process_commands_on_one_video_compute_each_stage_once(tmp_path, sample_video):
    data = tmp_path / "data"
    argv = [*process_argv(data, sample_video, until="lift"), "--json"]
    results = together(argv, argv)
    for code, _, err in results:
        assert code == 0, err[-2000:]
    keys = [sorted((r["stage"], r["key"]) for r in json.loads(out)) for _, out, _ in results]
    assert keys[0] == keys[1]
    assert [stage for stage, _ in keys[0]] == ["ingest", "lift", "pose"]
    assert computed(data) == {s: [("cached", 1), ("done", 1)] for s in ("ingest", "lift", "pose")}
    assert query(data, "SELECT count(*) FROM stage_claims") == [(0,)]


def test_two_trainings_of_one_run_train_once(tmp_path, sample_run, sample_dataset):
    data = copy_data(sample_run, tmp_path / "data")
    argv = [
        *["--data", str(data), "train", "--dataset", sample_dataset, *TINY_TRAIN_FLAGS],
        *["--train-seed", "11", "--train-iterations", "6", "--json"],
    ]
    results = together(argv, argv)
    for code, _, err in results:
        assert code == 0, err[-2000:]
    summaries = [json.loads(out)[0] for _, out, _ in results]
    assert summaries[0]["key"] == summaries[1]["key"]
    assert sorted(s["state"] for s in summaries) == ["cached", "done"]
    trained = query(
        data,
        "SELECT state, count(*) FROM stage_runs WHERE stage = 'train' AND key = ? "
        "GROUP BY ALL ORDER BY ALL",
        [summaries[0]["key"]],
    )
    assert trained == [("cached", 1), ("done", 1), ("running", 1)]


def test_a_claim_held_by_a_live_run_waits_and_one_of_a_killed_process_is_taken_over(tmp_path):
    db = tmp_path / "ringside.duckdb"
    # A process that is gone: this one's child, run to its end.
    gone = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        text=True,
        capture_output=True,
        check=True,
    ).stdout.strip()
    host = this_worker().rpartition(":")[0]
    with connect(db) as con:
        con.execute(
            "INSERT INTO stage_claims VALUES ('pose', 'v', 'k', ?, now())", [f"{host}:{gone}/1"]
        )
        assert take_claim(con, "pose", "v", "k") is None  # taken over

    order = []

    def second() -> None:
        with claimed(db, "pose", "v", "k", lambda holder: order.append(f"waits for {holder}")):
            order.append("second computes")

    with claimed(db, "pose", "v", "k") as waited:
        assert not waited
        thread = threading.Thread(target=second)
        thread.start()
        time.sleep(1.5)
        order.append("first commits")
    thread.join(timeout=10)
    assert [line.split(" for ")[0] for line in order] == [
        "waits",
        "first commits",
        "second computes",
    ]
    with connect(db, read_only=True) as con:
        assert con.execute("SELECT count(*) FROM stage_claims").fetchone() == (0,)
