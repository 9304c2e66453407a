"""One computation per stage output at a time: two commands on one video, or on one dataset's
training, at the same moment compute each output once; the other waits and reuses it. The claim
of a killed process passes on at once."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

from conftest import copy_data, process_argv, query
from tiny import TINY_TRAIN_FLAGS

from storage.claims import claimed
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
    assert list((data / "claims").iterdir()) == []


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


HOLD = """
import sys, time
from pathlib import Path
from storage.claims import claimed

with claimed(Path(sys.argv[1]), "pose", "v", "k"):
    print("holding", flush=True)
    time.sleep(600)
"""


def test_a_claim_held_by_a_live_run_waits_and_one_of_a_killed_process_passes_on(tmp_path):
    folder = tmp_path / "claims"
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(folder)], cwd=REPO, stdout=subprocess.PIPE, text=True
    )
    assert holder.stdout.readline().strip() == "holding"
    said = []
    done = threading.Event()

    def second() -> None:
        with claimed(folder, "pose", "v", "k", said.append) as waited:
            assert waited
            done.set()

    thread = threading.Thread(target=second)
    thread.start()
    time.sleep(1.0)
    assert not done.is_set() and said == [f"{this_worker().rpartition(':')[0]}:{holder.pid}"]
    holder.kill()  # SIGKILL while holding: the kernel lets go of its lock
    holder.wait()
    thread.join(timeout=10)
    assert done.is_set()

    # Threads of one process claim apart too, in turn.
    order = []

    def another() -> None:
        with claimed(folder, "pose", "v", "k", lambda _: order.append("waits")):
            order.append("second computes")

    with claimed(folder, "pose", "v", "k") as waited:
        assert not waited
        thread = threading.Thread(target=another)
        thread.start()
        time.sleep(1.0)
        order.append("first commits")
    thread.join(timeout=10)
    assert order == ["waits", "first commits", "second computes"]
    assert list(folder.iterdir()) == []  # no lock file outlives its claim
