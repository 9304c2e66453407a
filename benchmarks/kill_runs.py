"""Kill `ringside process` with SIGKILL at random moments, again and again; then see what is left.

    python benchmarks/kill_runs.py [--kills 20] [--seed 0]

On the bundled sample, in a data directory of its own, with the tests' tiny training and
evaluation settings (so that kills land in every stage, training checkpoints included): each
round starts the pipeline and sends SIGKILL to the command's process alone at a random moment
within the time an uninterrupted run takes. Every process below it is noted just before (by
parent pid, with its start time, not by name) and counted again once they have had 5 s to go.
Each round has a data directory of its own, so kills land in every stage; after the kill the
same command runs to the end there, and the round counts as clean when no process was left, no
temporary file is in the artifact store, `ringside check` finds nothing damaged and the
per-video stages' keys equal an uninterrupted run's. Last line: the clean rounds of those where
the kill came before the run finished.
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
# The tests' tiny training and evaluation settings (tests/tiny.py, free of conftest's set-up).
sys.path.insert(0, str(REPO / "tests"))

from tiny import TINY_PIPELINE  # noqa: E402

from storage.check import scan  # noqa: E402
from storage.db import connect  # noqa: E402
from storage.paths import data_paths  # noqa: E402

ASSETS = data_paths().assets
SAMPLE = ASSETS / "samples" / "multi_person" / "cam01.mp4"
# The runs' data directories share these assets (weights, the sample) rather than pull their own.
ENV = {**os.environ, "RINGSIDE_ASSETS": str(ASSETS)}
# More iterations than the tests' tiny run, checkpointed often: kills land mid-checkpoint too.
SETTINGS = {**TINY_PIPELINE, "train.iterations": "40", "train.checkpoint_every": "5"}


def command(data: Path) -> list[str]:
    flags = [
        p for k, v in SETTINGS.items() for p in ("--" + k.replace(".", "-").replace("_", "-"), v)
    ]
    ringside = [sys.executable, "-m", "flows.cli", "--data", str(data)]
    return [*ringside, "process", str(SAMPLE), "--adversary", "A", *flags]


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


def run(data: Path) -> float:
    start = time.monotonic()
    subprocess.run(command(data), check=True, capture_output=True, cwd=REPO, env=ENV)
    return time.monotonic() - start


def contents(data: Path) -> list:
    with connect(data_paths(data).db, read_only=True) as con:
        return con.execute(
            "SELECT stage, video_id, key FROM stage_outputs "
            "WHERE stage IN ('ingest', 'pose', 'lift', 'dataset') ORDER BY ALL"
        ).fetchall()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if not SAMPLE.exists():
        sys.exit(f"no sample video at {SAMPLE}: run `ringside assets pull` first")
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory(prefix="ringside-kills-") as tmp:
        whole = Path(tmp) / "whole"
        took = run(whole)
        print(f"an uninterrupted run: {took:.0f} s")
        clean = killed = 0
        for kill in range(args.kills):
            data = Path(tmp) / f"killed-{kill}"
            victim = subprocess.Popen(
                command(data),
                cwd=REPO,
                env=ENV,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                start_new_session=True,
            )
            at = rng.uniform(1.0, took)
            try:
                victim.wait(timeout=at)
                print(f"kill {kill + 1}: the run finished before {at:.1f} s")
                continue
            except subprocess.TimeoutExpired:
                tree = {victim.pid: _stat(victim.pid)[1], **descendants(victim.pid)}
                victim.kill()  # the command only: what it started must end by itself
                victim.wait()
            killed += 1
            time.sleep(5)
            left = survivors(tree)
            # The same command again, to the end: what the kill left behind is cleared.
            run(data)
            artifacts = data_paths(data).artifacts
            temporaries = sorted(str(p) for p in artifacts.glob("*/.tmp-*"))
            problems = [p.what for p in scan(data_paths(data).db, artifacts)]
            same = contents(data) == contents(whole)
            clean += not left and not temporaries and not problems and same
            print(
                f"kill {kill + 1} at {at:.1f} s ({len(tree)} processes): {len(left)} left "
                f"{left}; after the rerun {len(temporaries)} temporary files, check "
                f"{problems or 'clean'}, per-video results as uninterrupted: {same}"
            )
            shutil.rmtree(data)
    print(f"kills_leaving_nothing: {clean}/{killed}")


if __name__ == "__main__":
    main()
