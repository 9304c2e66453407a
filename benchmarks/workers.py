"""Four videos through `ringside serve --workers N`: one worker against two, in the same run.

    python benchmarks/workers.py [--until pose]

Input: the bundled two-person sample's four camera views (100 frames each, 1088x1920). For N = 1
and then 2, in a fresh data directory each: `ringside serve --workers N`, then four
`ringside schedule VIDEO --until STAGE` runs, timed from the first schedule to the end of the
last run (Prefect's end times). Checks both data directories hold the same per-video rows and
metrics. Last line: one worker's time over two workers' (above 1: two are faster).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from datetime import datetime
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

from conftest import stage_contents  # noqa: E402

from flows.launch import run_progress, served_api  # noqa: E402
from flows.serve import free_port  # noqa: E402
from storage.assets import SAMPLE_VIDEO  # noqa: E402
from storage.paths import data_paths  # noqa: E402


def wait(what: str, check, timeout_s: float = 900.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if found := check():
            return found
        time.sleep(0.5)
    sys.exit(f"timed out waiting for {what}")


def end_time(api: str, run_id: str) -> datetime:
    request = urllib.request.Request(
        f"{api}/flow_runs/{run_id}", headers={"Content-Type": "application/json"}
    )
    with urllib.request.urlopen(request, timeout=10) as answer:
        return datetime.fromisoformat(json.loads(answer.read())["end_time"])


def four_videos(data: Path, workers: int, until: str, env: dict[str, str]) -> float:
    videos = [(data_paths().assets / SAMPLE_VIDEO).with_name(f"cam0{i}.mp4") for i in range(1, 5)]
    paths = data_paths(data)
    ringside = [sys.executable, "-m", "flows.cli", "--data", str(data)]
    serve = subprocess.Popen(
        [*ringside, "serve", "--port", str(free_port()), "--workers", str(workers)],
        cwd=REPO,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        api = wait("`ringside serve`", lambda: served_api(paths))
        started = datetime.now().astimezone()
        runs = []
        for video in videos:
            command = [*ringside, "schedule", str(video), "--adversary", "A", "--until", until]
            done = subprocess.run(
                [*command, "--json"], cwd=REPO, env=env, capture_output=True, text=True
            )
            if done.returncode != 0:
                sys.exit(done.stderr.strip()[-2000:])
            runs.append(json.loads(done.stdout)["flow_run_id"])
        for run in runs:
            progress = wait(
                "the runs", lambda run=run: (p := run_progress(paths, run)).finished and p
            )
            if not progress.succeeded:
                sys.exit(f"run {run} failed: {progress.message}")
        return (max(end_time(api, run) for run in runs) - started).total_seconds()
    finally:
        serve.send_signal(signal.SIGTERM)
        serve.wait(timeout=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--until", default="pose", choices=("ingest", "pose", "lift", "dataset"))
    args = parser.parse_args()
    env = {k: v for k, v in os.environ.items() if k not in ("PREFECT_HOME", "PREFECT_API_URL")}
    env["RINGSIDE_ASSETS"] = str(data_paths().assets)
    with tempfile.TemporaryDirectory(prefix="ringside-workers-") as tmp:
        took = {}
        for workers in (1, 2):
            took[workers] = four_videos(Path(tmp) / f"w{workers}", workers, args.until, env)
            print(f"{workers} worker(s): four videos to {args.until} in {took[workers]:.1f} s")
        same = stage_contents(Path(tmp) / "w1") == stage_contents(Path(tmp) / "w2")
        print(f"per-video rows and metrics the same with one and two workers: {same}")
    print(f"one_over_two_workers: {took[1] / took[2]:.2f} x")


if __name__ == "__main__":
    main()
