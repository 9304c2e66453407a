"""How long SIGTERM takes to end `ringside process` in the pose stage, on an idle machine and with
two busy processes beside it (CI's two cores shared).

Each trial runs the sample in a new data directory, sends SIGTERM 3 s after the database
appears (the pose stage is at work then) and times the exit. The baseline, in the same run,
is the same command with the chunks' stop flag disabled: Prefect then waits for the running
chunk, as before the flag existed.

    python benchmarks/stop_latency.py

Linux only (its child processes are tied to its life with a parent-death signal).
"""

from __future__ import annotations

import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from flows.serve import die_with_parent  # noqa: E402
from storage.assets import SAMPLE_VIDEO, pull  # noqa: E402
from storage.files import scratch_dir  # noqa: E402
from storage.paths import data_paths  # noqa: E402

TRIALS = 3
# The command as `python -m flows.cli`, or with the flag the pose flow sets made inert.
COMMAND = "import runpy\nrunpy.run_module('flows.cli', run_name='__main__')"
NO_FLAG = (
    "import tasks.pose.task, threading\n"
    "class Inert(threading.Event):\n"
    "    def set(self):\n"
    "        pass\n"
    "tasks.pose.task.STOP = Inert()\n" + COMMAND
)
LINE = "ringside: error: stopped by SIGTERM; the same command picks up where it stopped"


def stop_seconds(video: Path, assets: Path, program: str) -> float:
    """Seconds from SIGTERM to the exit of one `ringside process` of ``video``."""
    env = {k: v for k, v in os.environ.items() if k not in ("PREFECT_HOME", "PREFECT_API_URL")}
    env["RINGSIDE_ASSETS"] = str(assets)
    with scratch_dir("bench") as tmp:
        data = Path(tmp) / "data"
        argv = ["--data", str(data), "process", str(video), "--adversary", "A"]
        command = subprocess.Popen(
            [sys.executable, "-c", program, *argv],
            cwd=REPO,
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            preexec_fn=die_with_parent,
        )
        try:
            deadline = time.monotonic() + 180
            while not (data / "ringside.duckdb").exists() and time.monotonic() < deadline:
                time.sleep(0.1)
            time.sleep(3)
            command.send_signal(signal.SIGTERM)
            sent = time.monotonic()
            _, err = command.communicate(timeout=120)
            seconds = time.monotonic() - sent
        finally:
            if command.poll() is None:
                command.kill()
                command.wait()
    if err.strip().splitlines()[-1:] != [LINE]:
        raise SystemExit(f"the command did not stop as expected:\n{err[-2000:]}")
    return seconds


def busy(count: int) -> list[subprocess.Popen]:
    loop = [sys.executable, "-c", "while True: pass"]
    return [subprocess.Popen(loop, preexec_fn=die_with_parent) for _ in range(count)]


def main() -> None:
    # Stopped, it still ends its busy processes and the command (`finally`); killed, they get
    # SIGTERM from the kernel as their parent dies.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    assets = data_paths().assets
    pull(assets, log=lambda _line: None)
    video = assets / SAMPLE_VIDEO
    results = {}
    for load in (0, 2):
        hogs = busy(load)
        try:
            for name, program in (("flag", COMMAND), ("baseline", NO_FLAG)):
                times = [stop_seconds(video, assets, program) for _ in range(TRIALS)]
                median = results[load, name] = statistics.median(times)
                shown = ", ".join(f"{t:.2f}" for t in times)
                print(f"{load} busy processes, {name:8s}: median {median:.2f} s ({shown})")
        finally:
            for hog in hogs:
                hog.kill()
                hog.wait()
    print(f"with two busy processes: {results[2, 'baseline'] / results[2, 'flag']:.1f}x faster")
    print(f"stop_latency_busy: {results[2, 'flag']:.2f} s")


if __name__ == "__main__":
    main()
