"""One computation per stage output at a time: two commands on one video, or on one dataset's
training, at the same moment compute each output once; the other waits and reuses it. The claim
of a killed process passes on at once."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from conftest import copy_data, process_argv, query
from tiny import TINY_TRAIN_FLAGS

from storage.claims import claimed
from storage.records import this_worker

REPO = Path(__file__).resolve().parent.parent


def ringside(*argv: str) -> subprocess.Popen:
    # Prefect's INFO logs on stderr: a command that waits for another's claim says so there.
    env = os.environ | {"PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL": "INFO"}
    return subprocess.Popen(
        [sys.executable, "-m", "flows.cli", *argv],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def together(*commands: list[str]) -> list[tuple[int, str, str, int]]:
    """Start the commands at once; (exit code, stdout, stderr, pid) of each."""
    return finish(*[ringside(*argv) for argv in commands])


def finish(*started: subprocess.Popen) -> list[tuple[int, str, str, int]]:
    """(exit code, stdout, stderr, pid) of each command once it has ended. Their pipes are
    read as they write (Prefect's logs would fill one and stall its command)."""
    with ThreadPoolExecutor(len(started)) as pool:
        said = list(pool.map(lambda p: p.communicate(timeout=900), started))
    return [(p.returncode, out, err, p.pid) for p, (out, err) in zip(started, said, strict=True)]


def waits(err: str) -> list[tuple[str, int]]:
    """The outputs a command waited for while another held their claim, as its log names
    them (`flows.runs.reuse_or_run`): (stage, pid of the command holding it), in order."""
    found = re.findall(r"(\S+) \w{12} of \S+ is being computed by \S+:(\d+): waiting for it", err)
    return [(stage, int(pid)) for stage, pid in found]


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
    for code, _, err, _ in results:
        assert code == 0, err[-2000:]
    keys = [sorted((r["stage"], r["key"]) for r in json.loads(out)) for _, out, _, _ in results]
    assert keys[0] == keys[1]
    assert [stage for stage, _ in keys[0]] == ["ingest", "lift", "pose"]
    assert computed(data) == {s: [("cached", 1), ("done", 1)] for s in ("ingest", "lift", "pose")}
    # The command that reused pose (19 s) and lift (10 s) had claimed each while the other
    # computed it, and waited (ingest, 4 s, may be committed before the later one starts).
    states = [{r["stage"]: r["state"] for r in json.loads(out)} for _, out, _, _ in results]
    pids = [pid for *_, pid in results]
    for stage in ("pose", "lift"):
        (reused,) = [k for k in (0, 1) if states[k][stage] == "cached"]
        assert (stage, pids[1 - reused]) in waits(results[reused][2]), results[reused][2][-2000:]
    for k in (0, 1):
        assert all(pid == pids[1 - k] for _, pid in waits(results[k][2]))
    assert list((data / "claims").iterdir()) == []


def test_two_trainings_of_one_run_train_once(tmp_path, sample_run, sample_dataset):
    data = copy_data(sample_run, tmp_path / "data")
    argv = [
        *["--data", str(data), "train", "--dataset", sample_dataset, *TINY_TRAIN_FLAGS],
        *["--train-seed", "11", "--train-iterations", "600", "--json"],
    ]
    # The second starts once the first holds the training's claim, and reaches the claim while
    # the first trains: 600 tiny iterations, ~18 s, against ~7 s for a command to start. (With
    # 6 iterations, started together, the second found the run committed and never waited.)
    first = ringside(*argv)
    deadline = time.monotonic() + 300
    while not list((data / "claims").glob("train-*.lock")):
        assert first.poll() is None and time.monotonic() < deadline, first.poll()
        time.sleep(0.05)
    results = finish(first, ringside(*argv))
    for code, _, err, _ in results:
        assert code == 0, err[-2000:]
    summaries = [json.loads(out)[0] for _, out, _, _ in results]
    assert summaries[0]["key"] == summaries[1]["key"]
    assert [s["state"] for s in summaries] == ["done", "cached"]
    assert waits(results[1][2]) == [("train", first.pid)]
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
