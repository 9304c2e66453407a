"""What each per-video stage costs per minute of footage: seconds, DuckDB bytes, artifact bytes.

    python benchmarks/stage_costs.py [--loops 40]

Input: the bundled two-person sample (1088x1920, 60 fps) looped 40 times into one file
(4,000 frames, 66.7 s). `ringside process --until STAGE` runs for ingest, pose, lift and
dataset in turn on one fresh data directory with the default settings. A stage's cost is the
command's wall-clock time less that of the same command run again at once (everything cached:
start-up and cache checks), and how much the DuckDB file and the artifact store grew. Everything
is divided by the footage's minutes. Training and evaluation do not scale with the
footage (their length is a setting) and are not measured here: see `benchmarks/train_speed.py`.
Last line: the four stages' seconds per minute of footage together.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from benchmarks._common import FPS, FRAMES, looped_sample  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.registry import per_video  # noqa: E402

STAGES = per_video()


def size(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def run(command: list[str], env: dict[str, str]) -> tuple[float, dict[str, str]]:
    """Wall-clock seconds of a `ringside process --json` command, and each stage's state."""
    start = time.perf_counter()
    done = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True)
    took = time.perf_counter() - start
    if done.returncode != 0:
        sys.exit(f"ringside process failed: {done.stderr.strip()[-2000:]}")
    return took, {row["stage"]: row["state"] for row in json.loads(done.stdout)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loops", type=int, default=40)
    args = parser.parse_args()
    # The run's data directory shares the pulled assets (weights, the sample).
    env = {**os.environ, "RINGSIDE_ASSETS": str(data_paths().assets)}
    with tempfile.TemporaryDirectory(prefix="ringside-costs-") as tmp:
        video = looped_sample(Path(tmp), args.loops)
        minutes = args.loops * FRAMES / FPS / 60
        data = Path(tmp) / "data"
        print(f"footage: {args.loops * FRAMES} frames, {minutes * 60:.1f} s")
        print(f"{'stage':8} {'s/min':>8} {'DuckDB MB/min':>14} {'artifacts MB/min':>17}")
        total = 0.0
        before = {"db": 0, "artifacts": 0}
        for stage in STAGES:
            command = [sys.executable, "-m", "flows.cli", "--data", str(data), "process"]
            command += [str(video), "--adversary", "A", "--until", stage, "--json"]
            took, states = run(command, env)
            assert states[stage] == "done", states
            after = {"db": size(data / "ringside.duckdb"), "artifacts": size(data / "artifacts")}
            # The same command again finds everything cached: what is left is start-up.
            overhead, states = run(command, env)
            assert set(states.values()) == {"cached"}, states
            grew = {k: (after[k] - before[k]) / 1e6 / minutes for k in after}
            before = after
            seconds = max(took - overhead, 0.0) / minutes
            total += seconds
            print(f"{stage:8} {seconds:8.1f} {grew['db']:14.2f} {grew['artifacts']:17.2f}")
        print(f"start-up and cache checks of one command: {overhead:.1f} s")
    print(f"per_video_stages_seconds_per_footage_minute: {total:.1f} s")


if __name__ == "__main__":
    main()
