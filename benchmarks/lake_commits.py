"""Commit latency and throughput of stage outputs: the data directory's DuckDB file against a
DuckLake catalog on PostgreSQL, with 1 writer and with 8 writer processes at once, in one run.

    python benchmarks/lake_commits.py [--commits 8] [--each 2]

Starts a PostgreSQL cluster of its own (`flows.postgres.start`, in a temporary folder, on a free
port; stopped at the end whatever happens) with two lakes: one as `storage.db.connect` attaches
it today, and one with DuckLake's data inlining (its catalog's ``data_inlining_row_limit`` set
to `INLINING_ROWS`, so that small inserts go to PostgreSQL's tables instead of a Parquet file
each; `storage.db` is unchanged, DuckLake reads the option from the catalog). Beside them, a
DuckDB file in the same folder, whose writers wait for its lock.

A commit is what `tasks.runner.run_stage` does, ``with connect(db) as con: write_output(...)``,
timed whole (opening, the migrations' check, the transaction, closing); it is also split into
its open (connect and close) and its write (`write_output` alone). Two outputs, shaped as the
tables each stage writes per video:

- ingest-like: 1 probe, 1 adversary, 3 shots and 4 chunks (records) and 30 metrics;
- pose-like: 100 keypoint rows (six FLOAT[33] columns and a FLOAT[99]), 100 observations
  (FLOAT[4]), 2 tracks and 2 media rows, and 30 metrics.

Each output is committed ``--commits`` times by one writer process, then ``--each`` times by
each of 8 writer processes started together (every commit a new video, as workers on
different videos commit), the three backends taking turns case by case. Prints per case the
median and p95 commit, the medians of its open and write, how many commits PostgreSQL refused
for a concurrent one meanwhile (errors in its log; each is run again), and the commits per
second with 8 writers; then whether every commit is there and reads back as written, and
whether a NaN inside a FLOAT[] column survives each backend. Last line,
``lake_commit_p50_8_writers: X ms``: the median commit of the pose-like output with 8 writers on
the lake as `storage.db` attaches it, the case issue 50's workers meet.

Linux, with PostgreSQL's server installed (Debian: `apt-get install postgresql`).
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import queue
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import flows.postgres  # noqa: E402
from flows.postgres import USER, PostgresError, server_programs  # noqa: E402
from flows.serve import free_port  # noqa: E402
from storage.db import connect  # noqa: E402
from storage.paths import Lake, lake_of  # noqa: E402
from storage.records import OutputRecord, write_output  # noqa: E402
from tasks.ingest.store import AdversaryRow, ChunkRow, ProbeRow, ShotRow  # noqa: E402
from tasks.pose.store import MediaRow, TrackRow  # noqa: E402

WRITERS = 8
# Rows per insert that the inlining lake keeps in PostgreSQL: both outputs' inserts (100 rows at
# most) fit; a whole video's pose keypoints (thousands of rows) would still go to Parquet.
INLINING_ROWS = 500
METRICS = 30
POSE_ROWS = 100
# How long the parent waits for one case's writers before it gives up.
CASE_TIMEOUT_S = 300.0


def ingest_output(rng: np.random.Generator) -> tuple[dict, dict[str, float]]:
    """Rows and metrics shaped as the ingest stage's for a short video (`tasks.ingest.stage`)."""
    shots = [
        ShotRow(s, 100 * s, 100 * (s + 1), float(rng.random()), f"{s:064x}.png") for s in range(3)
    ]
    rows = {
        "ingest_probes": [
            ProbeRow("/videos/bout.mp4", 60.0, 300, 300, 1920, 1088, "h264", 5.0, None)
        ],
        "ingest_adversaries": [AdversaryRow("A", "red", None)],
        "ingest_shots": shots,
        "ingest_chunks": [ChunkRow(c, min(c, 2), 75 * c, 75 * (c + 1)) for c in range(4)],
    }
    return rows, {f"metric_{i:02d}": float(rng.random()) for i in range(METRICS)}


def pose_output(rng: np.random.Generator, nan: bool = False) -> tuple[dict, dict[str, float]]:
    """Rows and metrics shaped as the pose stage's (`tasks.pose.stage`): 50 frames of two
    fighters' keypoints. ``nan``: the world points NaN, as a backend without them gives."""
    n = POSE_ROWS

    def floats(width: int) -> np.ndarray:
        return rng.standard_normal((n, width), dtype=np.float32)

    keypoints = {
        "frame": np.tile(np.arange(n // 2), 2),
        "role": np.array(["adversary", "opponent"]).repeat(n // 2),
        "track": np.array([0, 1]).repeat(n // 2),
        **{name: floats(33) for name in ("x", "y", "confidence", "raw_x", "raw_y")},
        "raw_confidence": floats(33),
        "world": np.full((n, 99), np.nan, np.float32) if nan else floats(99),
    }
    rows = {
        "pose_tracks": [
            TrackRow(t, 0, role, 0, n // 2 - 1, n // 2)
            for t, role in enumerate(("adversary", "opponent"))
        ],
        "pose_observations": {
            "frame": keypoints["frame"],
            "track": keypoints["track"],
            "score": rng.random(n),
            "box": floats(4),
        },
        "pose_keypoints": keypoints,
        "pose_media": [
            MediaRow("overlay", 0, f"{1:064x}.mp4"),
            MediaRow("still", 10, f"{2:064x}.png"),
        ],
    }
    return rows, {f"metric_{i:02d}": float(rng.random()) for i in range(METRICS)}


OUTPUTS = {"ingest": ingest_output, "pose": pose_output}
# A stage's settings, as stage_outputs.config holds them (a few dozen bytes of JSON).
CONFIG = {"chunk_frames": 300, "overlap_frames": 8, "pose_model": "", "threshold": 0.5}


def record(stage: str, video_id: str) -> OutputRecord:
    return OutputRecord(stage, video_id, "k" * 16, CONFIG, "bench", {"video": video_id}, "run", 1.0)


@dataclass(frozen=True)
class Task:
    """One writer's share of a case: ``count`` commits of ``stage``'s output to ``db``, starting
    at the wall-clock time ``start_at`` (so the writers of a case start together)."""

    db: Path | Lake
    stage: str
    tag: str
    count: int
    start_at: float


def writer_outputs(index: int) -> dict[str, tuple[dict, dict[str, float]]]:
    """Writer ``index``'s outputs by stage: random values, the same each time for one index."""
    rng = np.random.default_rng(index)
    return {stage: make(rng) for stage, make in OUTPUTS.items()}


def writer(index: int, inbox, outbox) -> None:
    """A writer process: runs the Tasks it is sent, answers (index, [(commit s, write s)], end
    wall-clock time), or (index, error line) when a commit fails."""
    # DuckDB draws a progress bar on stdout for a query over 2 s; the answers go by the queue.
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    outputs = writer_outputs(index)
    for task in iter(inbox.get, None):
        rows, metrics = outputs[task.stage]
        times = []
        time.sleep(max(0.0, task.start_at - time.time()))
        try:
            for i in range(task.count):
                out = record(task.stage, f"{task.tag}-w{index}-{i}")
                start = time.perf_counter()
                with connect(task.db) as con:
                    opened = time.perf_counter()
                    write_output(con, out, rows, metrics)
                    written = time.perf_counter()
                times.append((time.perf_counter() - start, written - opened))
        except Exception as error:  # reported by the parent, which stops the run
            outbox.put((index, f"{type(error).__name__}: {str(error).splitlines()[0]}"))
            continue
        outbox.put((index, times, time.time()))


def run_case(inboxes, outbox, task: Task, writers: int) -> tuple[list, float]:
    """``task`` on the first ``writers`` writers at once: every commit's (commit s, write s),
    and the wall time from the common start to the last writer's end."""
    for inbox in inboxes[:writers]:
        inbox.put(task)
    times, ends = [], []
    for _ in range(writers):
        try:
            answer = outbox.get(timeout=CASE_TIMEOUT_S)
        except queue.Empty:
            sys.exit(f"{task.tag}: the writers did not finish within {CASE_TIMEOUT_S:.0f} s")
        if len(answer) == 2:
            sys.exit(f"{task.tag}: writer {answer[0]} failed: {answer[1]}")
        times += answer[1]
        ends.append(answer[2])
    return times, max(ends) - task.start_at


def percentile_ms(values: list[float], q: float) -> float:
    return 1000 * float(np.percentile(values, q))


def make_catalog(port: int, name: str) -> None:
    where = ["-h", "127.0.0.1", "-p", str(port), "-U", USER]
    subprocess.run([str(server_programs() / "createdb"), *where, name], check=True)


def keypoints_read_back(db: Path | Lake, video_id: str, rows: dict) -> str:
    """Whether the pose_keypoints rows of ``video_id`` read back as ``rows`` holds them: "yes",
    or why not (NaN equal to NaN)."""
    want = rows["pose_keypoints"]
    try:
        with connect(db, read_only=True) as con:
            got = con.execute(
                "SELECT * FROM pose_keypoints WHERE video_id = ? ORDER BY role, frame", [video_id]
            ).fetchnumpy()
    except Exception as error:
        return f"no ({type(error).__name__}: {str(error).splitlines()[0]})"
    order = np.lexsort([want["frame"], want["role"]])
    for column, values in want.items():
        found = got[column]
        if values.ndim > 1:
            found = np.stack([np.asarray(v, np.float32) for v in found])
        if not np.array_equal(values[order], found, equal_nan=values.dtype.kind == "f"):
            return f"no (column {column} differs)"
    return "yes"


def refusals(log: Path, since: int) -> int:
    """The errors PostgreSQL logged after byte ``since`` of its ``log``: with nothing else
    talking to this cluster, the catalog commits it refused for a concurrent one."""
    with log.open("rb") as file:
        file.seek(since)
        return sum(b"ERROR:" in line for line in file)


def data_files(db: Path | Lake) -> str:
    if isinstance(db, Lake):
        return f"{sum(1 for _ in db.data_path.rglob('*.parquet'))} Parquet files"
    return f"{db.stat().st_size / 1e6:.1f} MB file"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--commits", type=int, default=8, help="commits of the single writer")
    parser.add_argument("--each", type=int, default=2, help="commits of each of the 8 writers")
    args = parser.parse_args()
    began = time.monotonic()
    tmp = Path(tempfile.mkdtemp(prefix="ringside-lake-commits-"))
    tmp.chmod(0o755)  # as root the server runs as `postgres`, who must reach its folder
    context = multiprocessing.get_context("spawn")
    inboxes = [context.Queue() for _ in range(WRITERS)]
    outbox = context.Queue()
    processes = []
    try:
        try:
            port, _ = flows.postgres.start(tmp / "postgres", free_port())
        except PostgresError as error:
            sys.exit(f"PostgreSQL: {error}")
        backends: dict[str, Path | Lake] = {
            "file": tmp / "ringside.duckdb",
            "lake": lake_of(flows.postgres.results_setting(port), tmp / "shared"),
        }
        make_catalog(port, "inlined")
        inlined = Lake(f"dbname=inlined host=127.0.0.1 port={port} user={USER}", tmp / "inlined")
        backends["lake+inlining"] = inlined
        # Migrated, and each table written once (an inlining lake makes its tables in
        # PostgreSQL then), here, not in the first timed commit.
        for db in backends.values():
            with connect(db) as con:
                if db is inlined:
                    con.execute(
                        f"CALL results.set_option('data_inlining_row_limit', {INLINING_ROWS})"
                    )
                for stage, (rows, metrics) in writer_outputs(0).items():
                    write_output(con, record(stage, f"warm-{stage}"), rows, metrics)
        for index in range(WRITERS):
            process = context.Process(target=writer, args=(index, inboxes[index], outbox))
            process.start()
            processes.append(process)
        # One commit per writer on the file and on a lake first: the imports and first loads
        # are not timed (the two lakes load the same extensions).
        for name in ("file", "lake"):
            task = Task(backends[name], "ingest", f"warm-{name}", 1, time.time())
            run_case(inboxes, outbox, task, WRITERS)
        print(
            f"outputs: ingest-like (1 probe, 1 adversary, 3 shots, 4 chunks, {METRICS} metrics); "
            f"pose-like ({POSE_ROWS} keypoint rows of 6 FLOAT[33] + FLOAT[99], {POSE_ROWS} "
            f"observations, 2 tracks, 2 media, {METRICS} metrics)"
        )
        print(
            "p50/p95 of a commit = `with connect(db) as con: write_output(...)` (as "
            "tasks.runner.run_stage); medians of its open (connect and close) and write "
            "(write_output); refused = commits PostgreSQL's catalog refused meanwhile (a "
            "concurrent update, a snapshot id taken), each run again by DuckLake or "
            "storage.db.transact"
        )
        print(f"lake+inlining: data_inlining_row_limit {INLINING_ROWS} in its catalog")
        header = f"{'backend':<14} {'output':<7} {'writers':>7} {'commits':>7} {'p50 ms':>7} "
        print(header + f"{'p95 ms':>7} {'open':>6} {'write':>6} {'refused':>7} {'commits/s':>9}")
        log = tmp / "postgres" / "server.log"
        results = {}
        # Backends interleaved, so that a change in the machine's load meets all three alike.
        for stage in OUTPUTS:
            for writers, count in ((1, args.commits), (WRITERS, args.each)):
                for name, db in backends.items():
                    logged = log.stat().st_size
                    tag = f"{name}-{stage}-{writers}"
                    task = Task(db, stage, tag, count, time.time() + 0.5)
                    times, wall = run_case(inboxes, outbox, task, writers)
                    commits, writes = [t[0] for t in times], [t[1] for t in times]
                    opens = [c - w for c, w in zip(commits, writes, strict=True)]
                    results[name, stage, writers] = statistics.median(commits)
                    rate = f"{len(times) / wall:9.1f}" if writers > 1 else f"{'':>9}"
                    print(
                        f"{name:<14} {stage:<7} {writers:>7} {len(times):>7} "
                        f"{percentile_ms(commits, 50):7.0f} {percentile_ms(commits, 95):7.0f} "
                        f"{percentile_ms(opens, 50):6.0f} {percentile_ms(writes, 50):6.0f} "
                        f"{refusals(log, logged):>7} {rate}"
                    )
        for inbox in inboxes:
            inbox.put(None)
        for process in processes:
            process.join(timeout=60)
        for name, db in backends.items():
            with connect(db, read_only=True) as con:
                (landed,) = con.execute(
                    "SELECT count(*) FROM stage_outputs WHERE video_id NOT LIKE 'warm-%'"
                ).fetchone()
            expected = len(OUTPUTS) * (args.commits + WRITERS * args.each)
            # Writer 0's first pose commit with one writer, against the rows it sent.
            same = keypoints_read_back(db, f"{name}-pose-1-w0-0", writer_outputs(0)["pose"][0])
            checks = [
                f"{landed} of {expected} outputs committed",
                f"read back as written: {same}",
                data_files(db),
            ]
            # Last, since a failure here may leave the table unreadable on this backend.
            rows, metrics = pose_output(np.random.default_rng(0), nan=True)
            with connect(db) as con:
                write_output(con, record("pose", f"nan-{name}"), rows, metrics)
            checks.append(
                f"NaN in FLOAT[] read back: {keypoints_read_back(db, f'nan-{name}', rows)}"
            )
            print(f"{name}: " + "; ".join(checks))
        for over, under in (("lake", "file"), ("lake+inlining", "lake")):
            ratios = ", ".join(
                f"{stage} {n} {results[over, stage, n] / results[under, stage, n]:.2f} x"
                for stage in OUTPUTS
                for n in (1, WRITERS)
            )
            print(f"p50 of {over} over {under} (output, writers): {ratios}")
        print(f"run took {time.monotonic() - began:.0f} s")
    finally:
        for process in processes:
            if process.is_alive():
                process.kill()
                process.join()
        flows.postgres.stop(tmp / "postgres")
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"lake_commit_p50_8_writers: {1000 * results['lake', 'pose', WRITERS]:.0f} ms")


if __name__ == "__main__":
    main()
