"""Stopping `ringside process` at random moments, then running it again: what must hold after a
kill (SIGKILL of the command alone) or a stop (SIGTERM). The slow test (tests/test_kills.py) and
`benchmarks/kill_runs.py` run these rounds; this file has no side effects (unlike conftest).

On the bundled sample with the tiny training and evaluation settings (a checkpoint every 5
iterations, so that stops land in every stage, checkpoint commits included): each round starts
the pipeline in a fresh data directory and signals the command's process alone at a random
moment within the time an uninterrupted run takes. Every process below it is noted just before
(by parent pid, with its start time, not by name) and looked for until all are gone, for 30 s at
most; how long the last took to go is noted (a private Prefect server gets SIGTERM as its parent
dies and shuts down in a second or two on an idle machine, several on a loaded one). Then the
same command runs to the end there: no temporary file may be left in the artifact store, `check`
must find nothing damaged and the per-video stages' outputs must equal an uninterrupted run's. A
SIGTERM must also end the command with exit 143 and one line.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from outputs import differences, stage_contents
from tiny import TINY_PIPELINE, flags

from storage.check import scan
from storage.paths import data_paths

REPO = Path(__file__).resolve().parent.parent
# More iterations than the tests' tiny run, checkpointed often: stops land mid-checkpoint too.
SETTINGS = {**TINY_PIPELINE, "train.iterations": "40", "train.checkpoint_every": "5"}
# How long the processes below a stopped command have to go before one left counts as a survivor.
GONE_WITHIN_S = 30.0
STOPPED_LINE = "ringside: error: stopped by SIGTERM; the same command picks up where it stopped"


def command(data: Path, video: Path) -> list[str]:
    ringside = [sys.executable, "-m", "flows.cli", "--data", str(data)]
    return [*ringside, "process", str(video), "--adversary", "A", *flags(SETTINGS)]


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
    """Run the command to the end; its seconds."""
    start = time.monotonic()
    subprocess.run(command(data, video), check=True, capture_output=True, cwd=REPO)
    return time.monotonic() - start


@dataclass
class Round:
    """One stopped run and the rerun after it."""

    how: str  # "SIGKILL" or "SIGTERM"
    at_s: float
    processes: int
    exit: int
    said: list[str]  # the lines the stopped command wrote to stderr
    left: list[str] = field(default_factory=list)
    gone_s: float = 0.0  # from the signal until the last process below it had gone
    temporaries: list[str] = field(default_factory=list)
    damaged: list[str] = field(default_factory=list)
    differs: list[str] = field(default_factory=list)
    rerun_s: float = 0.0

    @property
    def problems(self) -> list[str]:
        found = self.left + self.temporaries + self.damaged + self.differs
        if self.how == "SIGTERM" and (self.exit != 143 or self.said != [STOPPED_LINE]):
            found.append(f"SIGTERM: exit {self.exit}, said {self.said}")
        return found


def stop_and_rerun(
    data: Path, video: Path, at_s: float, how: signal.Signals, expected: dict
) -> Round | None:
    """Start the command in ``data``, send ``how`` to it alone after ``at_s``, look for what is
    left, run it again to the end and compare with ``expected`` (`stage_contents` of an
    uninterrupted run). None when it finished before its moment."""
    victim = subprocess.Popen(
        command(data, video),
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        victim.wait(timeout=at_s)
        victim.communicate()
        return None
    except subprocess.TimeoutExpired:
        tree = {victim.pid: _stat(victim.pid)[1], **descendants(victim.pid)}
        signalled = time.monotonic()
        victim.send_signal(how)  # the command only: what it started must end by itself
        _, err = victim.communicate(timeout=120)
    while (left := survivors(tree)) and time.monotonic() - signalled < GONE_WITHIN_S:
        time.sleep(0.2)
    stopped = Round(
        how.name,
        round(at_s, 1),
        len(tree),
        victim.returncode,
        [line for line in err.strip().splitlines() if line.strip()],
        left=left,
        gone_s=round(time.monotonic() - signalled, 1),
    )
    stopped.rerun_s = round(run(data, video), 1)
    artifacts = data_paths(data).artifacts
    stopped.temporaries = sorted(str(p) for p in artifacts.glob("*/.tmp-*"))
    stopped.damaged = [p.what for p in scan(data_paths(data).db, artifacts)]
    stopped.differs = differences(stage_contents(data), expected)
    return stopped
