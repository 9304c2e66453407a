"""Four videos through `ringside serve --workers N`: one worker against two, on the data
directory's DuckDB file and on a DuckLake catalog on PostgreSQL, in the same run.

    python benchmarks/workers.py [--until pose] [--backend file|lake|both]

Input: the bundled two-person sample's four camera views (100 frames each, 1088x1920). For each
run, a fresh data directory: `ringside serve --workers N`, then four
`ringside schedule VIDEO --until STAGE` runs, timed from the first schedule to the end of the
last run (Prefect's end times). A lake run's `ringside` commands get `--results LAKE --shared DIR`
(serve's workers inherit them); each lake run has a fresh catalog database and shared folder in
one PostgreSQL cluster the benchmark starts (`flows.postgres.start`, in the temporary folder, on
a free port) and stops at the end whatever happens. The runs alternate, file-1, lake-1, file-2,
lake-2, so that the machine's load falls on both backends alike.

Checks that every run holds the same per-video rows and metrics (one worker against two, and
the lake against the file: `stage_contents` hashes rows as text, so the backends agree) and
that no lake run left a DuckDB file in its data directory (if runs differ, it names any source of
`tasks`/`models` edited meanwhile: the keys hash it, so such an edit alone changes them). Prints
a table of the runs: seconds, two workers' speed-up over one, and the lake's time over the
file's. Last line: the lake's one worker's time over two workers' (above 1: two are faster), the
case issue 50's shared results are for (the file's only with ``--backend file``).

Linux; a lake run needs PostgreSQL's server (Debian: `apt-get install postgresql`).
"""

from __future__ import annotations

import argparse
import hashlib
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

# tests/outputs.py, not conftest: conftest has side effects (environment, fixtures).
from outputs import differences, stage_contents  # noqa: E402

import flows.postgres  # noqa: E402
from flows.launch import run_progress, served_api  # noqa: E402
from flows.postgres import USER, server_programs  # noqa: E402
from flows.serve import free_port  # noqa: E402
from storage.assets import SAMPLE_VIDEO  # noqa: E402
from storage.paths import Lake, data_paths  # noqa: E402

WORKERS = (1, 2)
# The packages whose source the stages' cache keys hash (`storage.keys.code_version`).
KEYED_SOURCES = ("tasks", "models")


def wait(what: str, check, log: Path, timeout_s: float = 900.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if found := check():
            return found
        time.sleep(0.5)
    fail(f"timed out waiting for {what}", log)


def fail(why: str, log: Path) -> None:
    """Exit with ``why`` and the end of serve's log (the temporary folder goes with the exit)."""
    tail = log.read_text(errors="replace").strip().splitlines()[-30:] if log.exists() else []
    sys.exit("\n".join([why, f"last lines of {log.name}:", *tail]))


def end_time(api: str, run_id: str) -> datetime:
    request = urllib.request.Request(
        f"{api}/flow_runs/{run_id}", headers={"Content-Type": "application/json"}
    )
    with urllib.request.urlopen(request, timeout=10) as answer:
        return datetime.fromisoformat(json.loads(answer.read())["end_time"])


def new_lake(port: int, name: str, shared: Path) -> Lake:
    """A fresh lake: an empty catalog database ``name`` in the cluster on ``port`` (as
    `tests/lakes.new_lake` makes one), ``shared`` its folder."""
    where = ["-h", "127.0.0.1", "-p", str(port), "-U", USER]
    subprocess.run([str(server_programs() / "createdb"), *where, name], check=True)
    return Lake(f"dbname={name} host=127.0.0.1 port={port} user={USER}", shared)


def four_videos(
    data: Path, lake: Lake | None, workers: int, until: str, env: dict[str, str]
) -> float:
    videos = [(data_paths().assets / SAMPLE_VIDEO).with_name(f"cam0{i}.mp4") for i in range(1, 5)]
    ringside = [sys.executable, "-m", "flows.cli", "--data", str(data)]
    if lake is None:
        paths = data_paths(data, "")  # "": the file, whatever this shell's $RINGSIDE_RESULTS
    else:
        ringside += ["--results", str(lake), "--shared", str(lake.shared)]
        paths = data_paths(data, str(lake), lake.shared)
    log = data.with_name(f"{data.name}-serve.log")
    with log.open("w") as out:
        serve = subprocess.Popen(
            [*ringside, "serve", "--port", str(free_port()), "--workers", str(workers)],
            cwd=REPO,
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    try:
        api = wait("`ringside serve`", lambda: served_api(paths), log)
        started = datetime.now().astimezone()
        runs = []
        for video in videos:
            command = [*ringside, "schedule", str(video), "--adversary", "A", "--until", until]
            done = subprocess.run(
                [*command, "--json"], cwd=REPO, env=env, capture_output=True, text=True
            )
            if done.returncode != 0:
                fail(done.stderr.strip()[-2000:], log)
            runs.append(json.loads(done.stdout)["flow_run_id"])
        for run in runs:
            progress = wait(
                "the runs", lambda run=run: (p := run_progress(paths, run)).finished and p, log
            )
            if not progress.succeeded:
                fail(f"run {run} failed: {progress.message}", log)
        return (max(end_time(api, run) for run in runs) - started).total_seconds()
    finally:
        serve.send_signal(signal.SIGTERM)
        try:
            serve.wait(timeout=120)
        except subprocess.TimeoutExpired:
            serve.kill()  # not left running after the benchmark
            serve.wait()


def sources() -> dict[str, str]:
    """Each keyed source file's digest: an edit during the run (this tree is shared) changes
    the keys of the runs after it, and their rows then differ by key alone."""
    return {
        str(path.relative_to(REPO)): hashlib.sha256(path.read_bytes()).hexdigest()
        for package in KEYED_SOURCES
        for path in sorted((REPO / package).rglob("*.py"))
    }


def table(took: dict[tuple[str, int], float]) -> list[str]:
    """One line per run: backend, workers, seconds, 2 workers' speed-up over 1 (on the 2-worker
    line), the lake's time over the file's with as many workers (on the lake's lines)."""
    lines = [f"{'backend':<8} {'workers':>7} {'seconds':>8} {'2 over 1':>9} {'lake/file':>10}"]
    for (backend, workers), seconds in took.items():
        speedup = lake_over_file = "-"
        if workers == 2 and (backend, 1) in took:
            speedup = f"{took[backend, 1] / seconds:.2f} x"
        if backend == "lake" and ("file", workers) in took:
            lake_over_file = f"{seconds / took['file', workers]:.2f} x"
        lines.append(f"{backend:<8} {workers:>7} {seconds:>8.1f} {speedup:>9} {lake_over_file:>10}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--until", default="pose", choices=("ingest", "pose", "lift", "dataset"))
    parser.add_argument("--backend", default="both", choices=("file", "lake", "both"))
    args = parser.parse_args()
    backends = ("file", "lake") if args.backend == "both" else (args.backend,)
    # Where the results go is the command line's choice: none of this shell's settings.
    dropped = ("PREFECT_HOME", "PREFECT_API_URL", "RINGSIDE_RESULTS", "RINGSIDE_SHARED")
    env = {k: v for k, v in os.environ.items() if k not in dropped}
    env["RINGSIDE_ASSETS"] = str(data_paths().assets)
    before = sources()
    with tempfile.TemporaryDirectory(prefix="ringside-workers-") as name:
        tmp = Path(name)
        tmp.chmod(0o755)  # as root the server runs as `postgres`, who must reach its folder
        postgres = tmp / "postgres"
        try:
            port = flows.postgres.start(postgres, free_port())[0] if "lake" in backends else 0
            took: dict[tuple[str, int], float] = {}
            contents: dict[tuple[str, int], dict] = {}
            for workers in WORKERS:
                for backend in backends:
                    data = tmp / f"{backend}-w{workers}"
                    lake = None
                    if backend == "lake":
                        lake = new_lake(port, f"lake_w{workers}", tmp / f"{data.name}-shared")
                    took[backend, workers] = four_videos(data, lake, workers, args.until, env)
                    print(
                        f"{backend}, {workers} worker(s): four videos to {args.until} in "
                        f"{took[backend, workers]:.1f} s",
                        flush=True,
                    )
                    if lake is not None and (files := sorted(data.rglob("*.duckdb"))):
                        sys.exit(f"a lake run wrote DuckDB files in its data directory: {files}")
                    contents[backend, workers] = stage_contents(lake or data)
        finally:
            # Stopped on success, failure and Ctrl-C alike; nothing to do if it never started.
            flows.postgres.stop(postgres)
    print("\n".join(table(took)))
    # One worker against two on each backend, and the lake against the file (with one worker;
    # with two it follows from the other three).
    pairs = [((backend, 1), (backend, 2)) for backend in backends]
    if len(backends) == 2:
        pairs.append((("file", 1), ("lake", 1)))
    unequal = []
    for a, b in pairs:
        differ = differences(contents[b], contents[a])
        names = f"{b[0]}-{b[1]} and {a[0]}-{a[1]}"
        print(f"per-video rows and metrics the same in {names}: {not differ}")
        if differ:
            more = f" and {len(differ) - 5} more" if len(differ) > 5 else ""
            unequal.append(f"{names}: {', '.join(differ[:5])}{more}")
    if unequal:
        after = sources()
        edited = sorted(p for p in before.keys() | after.keys() if before.get(p) != after.get(p))
        why = f" (sources the keys hash were edited during the run: {', '.join(edited)})"
        sys.exit("runs differ" + (why if edited else "") + ": " + "; ".join(unequal))
    headline = "lake" if "lake" in backends else "file"
    print(f"{headline}_two_workers_speedup: {took[headline, 1] / took[headline, 2]:.2f} x")


if __name__ == "__main__":
    main()
