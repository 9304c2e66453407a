"""Pose on a Dask cluster against the thread pool, on the same video, in the same run.

    python benchmarks/dask_pose.py

Input: the bundled two-person sample looped 8 times (800 frames, 1088x1920), ingested in chunks
of 100 frames (8 pose chunks). `ringside process --until pose` runs twice on it, each in a fresh
data directory after its ingest: once with `pose.workers` 2 (two threads of the command), once with
`RINGSIDE_DASK_ADDRESS` naming a `distributed.LocalCluster` of 2 worker processes of 1 thread
each, started here before the command. Prints the wall-clock seconds of both commands and, last,
threads over Dask (above 1: Dask is faster).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from benchmarks._common import looped_sample  # noqa: E402
from storage.paths import data_paths  # noqa: E402

LOOPS = 8
CHUNK_FRAMES = 100


def pose_seconds(data: Path, video: Path, env: dict[str, str], *flags: str) -> float:
    """Wall-clock seconds of `ringside process --until pose` on an ingested ``video`` (the
    command's start-up included, as a user waits for it; the chunks are Prefect tasks of their
    own, outside the pose stage's reported seconds)."""

    def process(until: str) -> float:
        command = [sys.executable, "-m", "flows.cli", "--data", str(data), "process", str(video)]
        command += ["--adversary", "A", "--until", until, "--json"]
        command += ["--ingest-chunk-frames", str(CHUNK_FRAMES), *flags]
        start = time.perf_counter()
        done = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True)
        took = time.perf_counter() - start
        if done.returncode != 0:
            sys.exit(f"ringside process failed: {done.stderr.strip()[-2000:]}")
        [row] = [s for s in json.loads(done.stdout) if s["stage"] == until]
        assert row["state"] == "done", row
        return took

    process("ingest")
    return process("pose")


def main() -> None:
    from dask import config as dask_config
    from distributed import LocalCluster

    env = {k: v for k, v in os.environ.items() if k != "RINGSIDE_DASK_ADDRESS"}
    # The runs' data directories share the pulled assets (weights, the sample).
    env["RINGSIDE_ASSETS"] = str(data_paths().assets)
    with tempfile.TemporaryDirectory(prefix="ringside-dask-") as tmp:
        video = looped_sample(Path(tmp), LOOPS)
        threads = pose_seconds(Path(tmp) / "threads", video, env, "--pose-workers", "2")
        print(f"thread pool (pose.workers 2): {threads:.1f} s")
        # Dask's scratch folder in ours, not its default /tmp/dask-scratch-space, which
        # outlives the run.
        with (
            dask_config.set({"temporary-directory": str(Path(tmp) / "dask")}),
            LocalCluster(
                n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
            ) as cluster,
        ):
            dask_env = {**env, "RINGSIDE_DASK_ADDRESS": cluster.scheduler_address}
            dask = pose_seconds(Path(tmp) / "dask", video, dask_env)
        print(f"Dask LocalCluster (2 workers x 1 thread): {dask:.1f} s")
    print(f"pose_threads_over_dask: {threads / dask:.2f} x")


if __name__ == "__main__":
    main()
