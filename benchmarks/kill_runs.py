"""Kill `ringside process` with SIGKILL at random moments, again and again; then see what is left.

    python benchmarks/kill_runs.py [--kills 20] [--seed 0]

On the bundled sample, in a data directory of its own, with the tests' tiny training and
evaluation settings (so that kills land in every stage, training checkpoints included): each
round starts the pipeline as a new process session and kills the whole session with SIGKILL at a
random moment within the time an uninterrupted run takes. After each kill it counts the
processes still in that session (by session id, not by name) once they have had 10 s to go.
Then one run to the end, and it checks: no temporary file in the artifact store, `ringside
check` finds nothing damaged, and the per-video stages' results equal an uninterrupted run's in
a data directory of their own. Last line: the kills after which nothing of ours was left.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
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

SAMPLE = data_paths().assets / "samples" / "multi_person" / "cam01.mp4"
# More iterations than the tests' tiny run, checkpointed often: kills land mid-checkpoint too.
SETTINGS = {**TINY_PIPELINE, "train.iterations": "40", "train.checkpoint_every": "5"}


def command(data: Path) -> list[str]:
    flags = [
        p for k, v in SETTINGS.items() for p in ("--" + k.replace(".", "-").replace("_", "-"), v)
    ]
    ringside = [sys.executable, "-m", "flows.cli", "--data", str(data)]
    return [*ringside, "process", str(SAMPLE), "--adversary", "A", *flags]


def in_session(sid: int) -> list[str]:
    """Processes whose session is ``sid``, as 'pid command'."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if os.getsid(int(entry.name)) == sid:
                found.append(f"{entry.name} {(entry / 'cmdline').read_bytes()[:80]!r}")
        except (ProcessLookupError, PermissionError, FileNotFoundError):
            continue
    return found


def run(data: Path) -> float:
    start = time.monotonic()
    subprocess.run(command(data), check=True, capture_output=True, cwd=REPO)
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
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory(prefix="ringside-kills-") as tmp:
        whole = Path(tmp) / "whole"
        took = run(whole)
        print(f"an uninterrupted run: {took:.0f} s")
        data, clean = Path(tmp) / "killed", 0
        for kill in range(args.kills):
            victim = subprocess.Popen(
                command(data),
                cwd=REPO,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                start_new_session=True,
            )
            at = rng.uniform(1.0, took)
            try:
                victim.wait(timeout=at)
                print(f"kill {kill + 1}: the run finished before {at:.1f} s")
            except subprocess.TimeoutExpired:
                os.killpg(victim.pid, signal.SIGKILL)
                victim.wait()
            time.sleep(10)
            left = in_session(victim.pid)
            clean += not left
            print(f"kill {kill + 1} at {at:.1f} s: {len(left)} processes left {left}")
        run(data)
        artifacts = data_paths(data).artifacts
        temporaries = sorted(str(p) for p in artifacts.glob("*/.tmp-*"))
        problems = scan(data_paths(data).db, artifacts)
        print(f"temporary files left: {len(temporaries)} {temporaries}")
        print(f"check: {len(problems)} problems {[p.what for p in problems]}")
        print(f"per-video results as an uninterrupted run's: {contents(data) == contents(whole)}")
    print(f"kills_leaving_nothing: {clean}/{args.kills}")


if __name__ == "__main__":
    main()
