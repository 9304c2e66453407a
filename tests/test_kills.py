"""SIGKILL at 20 random moments of `ringside process`, each time in a fresh data directory; then
see what is left. About 20 minutes on 2 cores, so it is marked ``slow``: `make test` leaves it
out (it would take CI's whole budget) and `make test-slow` runs it.

On the bundled sample with the tiny training and evaluation settings (a checkpoint every 5
iterations, so that kills land in every stage, checkpoint writes included): each round starts
the pipeline and sends SIGKILL to the command's process alone at a random moment within the time
an uninterrupted run takes. Every process below it is noted just before (by parent pid, with its
start time, not by name) and looked for again once they have had 5 s to go. Then the same
command runs to the end there: no temporary file may be left in the artifact store, `check` must
find nothing damaged and the per-video stages' outputs must equal an uninterrupted run's.
"""

from __future__ import annotations

import random
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import stage_contents
from tiny import TINY_PIPELINE

from storage.check import scan
from storage.paths import data_paths

REPO = Path(__file__).resolve().parent.parent
KILLS = 20
# More iterations than the tests' tiny run, checkpointed often: kills land mid-checkpoint too.
SETTINGS = {**TINY_PIPELINE, "train.iterations": "40", "train.checkpoint_every": "5"}


def command(data: Path, video: Path) -> list[str]:
    flags = [
        p for k, v in SETTINGS.items() for p in ("--" + k.replace(".", "-").replace("_", "-"), v)
    ]
    ringside = [sys.executable, "-m", "flows.cli", "--data", str(data)]
    return [*ringside, "process", str(video), "--adversary", "A", *flags]


def _stat(pid: int) -> tuple[int, str] | None:
    """(parent pid, start time) of a live process, or None."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return None
    return int(fields[1]), fields[19]


def descendants(root: int) -> dict[int, str]:
    """Every live process below ``root`` (by parent pid), with its start time."""
    parents = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and (stat := _stat(int(entry.name))) is not None:
            parents[int(entry.name)] = stat
    found, frontier = {}, [root]
    while frontier:
        pid = frontier.pop()
        for child, (parent, started) in parents.items():
            if parent == pid and child not in found:
                found[child] = started
                frontier.append(child)
    return found


def survivors(before: dict[int, str]) -> list[str]:
    """The processes of ``before`` still alive (the same pid and start time), with commands."""
    left = []
    for pid, started in before.items():
        stat = _stat(pid)
        if stat is not None and stat[1] == started:
            command = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")[:80]
            left.append(f"{pid} {command.decode(errors='replace')}")
    return left


def run(data: Path, video: Path) -> float:
    start = time.monotonic()
    subprocess.run(command(data, video), check=True, capture_output=True, cwd=REPO)
    return time.monotonic() - start


@pytest.mark.slow
def test_twenty_kills_leave_no_process_no_temporary_file_and_the_same_results(
    tmp_path, sample_video
):
    rng = random.Random(0)
    whole = tmp_path / "whole"
    took = run(whole, sample_video)
    expected = stage_contents(whole)
    rounds = []
    while len(rounds) < KILLS:
        data = tmp_path / f"killed-{len(rounds)}"
        victim = subprocess.Popen(
            command(data, sample_video),
            cwd=REPO,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        at = rng.uniform(1.0, 0.9 * took)
        try:
            victim.wait(timeout=at)
            continue  # it finished before its moment: no kill, another round
        except subprocess.TimeoutExpired:
            tree = {victim.pid: _stat(victim.pid)[1], **descendants(victim.pid)}
            victim.kill()  # the command only: what it started must end by itself
            victim.wait()
        time.sleep(5)
        left = survivors(tree)
        # The same command again, to the end: what the kill left behind is cleared.
        run(data, sample_video)
        artifacts = data_paths(data).artifacts
        rounds.append(
            {
                "at_s": round(at, 1),
                "processes": len(tree),
                "left": left,
                "temporaries": sorted(str(p) for p in artifacts.glob("*/.tmp-*")),
                "damaged": [p.what for p in scan(data_paths(data).db, artifacts)],
                "differs": _differences(stage_contents(data), expected),
            }
        )
        print(rounds[-1], flush=True)
    assert [r for r in rounds if r["left"] or r["temporaries"] or r["damaged"]] == []
    assert [r for r in rounds if r["differs"]] == []


def _differences(found: dict, expected: dict) -> list[str]:
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
