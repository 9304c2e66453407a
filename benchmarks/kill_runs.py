"""Stop `ringside process` at random moments and run it again: 20 SIGKILLs of the command alone
and 10 SIGTERMs, each in a fresh data directory, on the bundled sample with the tiny pipeline
settings (tests/kill_rounds.py says what each round checks: no process or temporary file left,
nothing damaged, the same outputs as an uninterrupted run; a SIGTERM ends with exit 143 and one
line). Also how long the rerun after each stop takes, as a share of an uninterrupted run in the
same session: what resuming saves.

    python benchmarks/kill_runs.py [--kills 20] [--terms 10] [--seed 0]

About 30 minutes on 2 cores. Linux only (/proc).
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import statistics
import sys
import tempfile
from dataclasses import asdict
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

from kill_rounds import run, stop_and_rerun  # noqa: E402
from outputs import stage_contents  # noqa: E402

from storage.assets import SAMPLE_VIDEO, pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kills", type=int, default=20)
    parser.add_argument("--terms", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    assets = data_paths().assets
    pull(assets, log=lambda _line: None)
    # Each round's data directory shares this one's assets, as the tests' do.
    os.environ["RINGSIDE_ASSETS"] = str(assets)
    video = assets / SAMPLE_VIDEO
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory(prefix="kill-runs-") as scratch:
        root = Path(scratch)
        took = run(root / "whole", video)
        expected = stage_contents(root / "whole")
        print(f"an uninterrupted run: {took:.1f} s", flush=True)
        rounds = []
        wanted = [signal.SIGKILL] * args.kills + [signal.SIGTERM] * args.terms
        attempt = 0
        for how in wanted:
            stopped = None
            while stopped is None:
                attempt += 1
                at = rng.uniform(1.0, 0.9 * took)
                stopped = stop_and_rerun(root / f"round-{attempt}", video, at, how, expected)
            rounds.append(stopped)
            summary = {k: v for k, v in asdict(stopped).items() if v not in ([], "")}
            print({**summary, "problems": stopped.problems}, flush=True)
    for name in ("SIGKILL", "SIGTERM"):
        these = [r for r in rounds if r.how == name]
        if these:
            clean = sum(not r.problems for r in these)
            print(f"{name}: {clean} of {len(these)} rounds clean", flush=True)
    gone = [r.gone_s for r in rounds]
    print(
        f"processes below a stopped command all gone: median {statistics.median(gone):.1f} s, "
        f"at most {max(gone):.1f} s after the signal"
    )
    shares = [r.rerun_s / took for r in rounds]
    print(
        f"rerun after a stop: median {statistics.median(shares):.2f}, "
        f"range {min(shares):.2f}-{max(shares):.2f} of an uninterrupted run ({took:.1f} s)"
    )
    clean = sum(not r.problems for r in rounds)
    print(f"kill_runs_clean: {100 * clean / len(rounds):.1f} % of {len(rounds)} rounds")


if __name__ == "__main__":
    main()
