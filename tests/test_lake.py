"""The lake backend's foundations, on real PostgreSQL and DuckDB: the migrations' DDL as a DuckLake
catalog takes it (`storage.db.lake_ddl`), many writer processes committing at once
(`storage.records.write_output`, `storage.db.transact`), the claims across machines
(`storage.claims.lake_claimed`), SIGKILL in the middle of a commit, and PostgreSQL restarted
under a run (`storage.db.connect`'s wait, `CatalogUnreachable`).

The writers are separate processes (`sys.executable -c`), as machines would be: each has its own
DuckDB, its own PostgreSQL connections. What they measure (conflicts retried, commit latencies)
is printed (`pytest -s` shows it)."""

from __future__ import annotations

import asyncio
import json
import queue
import random
import re
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import asyncpg
import duckdb
import numpy as np
import pytest
from lakes import new_lake, start_cluster, stop_cluster
from pace import PACE

import flows.postgres
from storage.claims import lake_claimed, libpq_settings
from storage.db import CatalogUnreachable, _open_lake, connect, lake_ddl, migrations
from storage.paths import Lake
from storage.records import OutputRecord, write_output
from tasks.registry import registered

REPO = Path(__file__).resolve().parent.parent


class Child:
    """A Python process running ``code`` (``sys.executable -c``), its stdout read line by line
    on a thread of ours (so that waiting for a line can time out), its stderr kept in a file."""

    def __init__(self, code: str, *args: object, log: Path) -> None:
        self.log = log
        with log.open("w") as err:
            self.process = subprocess.Popen(
                [sys.executable, "-c", code, *map(str, args)],
                cwd=REPO,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
            )
        self.pid = self.process.pid
        self._lines: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.process.stdout:
            self._lines.put(line.rstrip("\n"))
        self._lines.put(None)

    def line(self, timeout_s: float) -> str:
        """The next line it prints; AssertionError (with its stderr) if none comes in time."""
        try:
            line = self._lines.get(timeout=timeout_s)
        except queue.Empty:
            message = f"child {self.pid}: no line in {timeout_s} s\n{self.said()}"
            raise AssertionError(message) from None
        if line is None:
            code = self.process.wait()
            raise AssertionError(f"child {self.pid} ended (exit {code})\n{self.said()}")
        return line

    def quiet_for(self, seconds: float) -> str | None:
        """The line it prints within ``seconds``, or None when it prints none."""
        try:
            line = self._lines.get(timeout=seconds)
        except queue.Empty:
            return None
        return "<ended>" if line is None else line

    def send(self, text: str) -> None:
        self.process.stdin.write(text + "\n")
        self.process.stdin.flush()

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
        self.process.wait()

    def said(self) -> str:
        return self.log.read_text(errors="replace")[-3000:]


@pytest.fixture
def spawn(tmp_path: Path) -> Iterator:
    """Starts `Child` processes; any still running at the end of the test is killed."""
    started: list[Child] = []

    def start(code: str, *args: object) -> Child:
        child = Child(code, *args, log=tmp_path / f"child-{len(started)}.err")
        started.append(child)
        return child

    yield start
    for child in started:
        child.kill()


def rolled_back(lake: Lake) -> int:
    """PostgreSQL's count of transactions rolled back in the lake's catalog database. DuckLake
    runs each commit in one, and runs it again itself (`ducklake_max_retry_count`) when
    PostgreSQL refuses it for a concurrent one: retries `transact` never sees. (Readers' ends
    count too, a few per connection: an upper bound of those retries.)"""

    async def ask() -> int:
        con = await asyncpg.connect(**libpq_settings(lake.catalog))
        try:
            return await con.fetchval(
                "SELECT xact_rollback FROM pg_stat_database WHERE datname = current_database()"
            )
        finally:
            await con.close()

    return asyncio.run(ask())


def summary(seconds: list[float]) -> str:
    ordered = sorted(seconds)
    p90 = ordered[int(0.9 * (len(ordered) - 1))]
    return f"median {statistics.median(ordered):.3f} s, p90 {p90:.3f} s, max {ordered[-1]:.3f} s"


# -- 1. The migrations on a lake -------------------------------------------------------------

COLUMNS = (
    "SELECT table_name, column_name, data_type, is_nullable FROM duckdb_columns() "
    "WHERE database_name = current_database() AND schema_name = 'main' "
    "ORDER BY table_name, column_index"
)


def tables(con: duckdb.DuckDBPyConnection) -> dict[str, list[tuple[str, str, bool]]]:
    """Each table's columns, in order: (name, type, nullable)."""
    found: dict[str, list[tuple[str, str, bool]]] = {}
    for table, column, kind, nullable in con.execute(COLUMNS).fetchall():
        found.setdefault(table, []).append((column, kind, nullable))
    return found


def without_comments(sql: str) -> str:
    return re.sub(r"--[^\n]*", "", sql)


def test_every_migration_makes_on_a_lake_the_tables_of_the_file(lake: Lake, tmp_path: Path):
    stage_sql = [p.read_text() for p in sorted((REPO / "tests/pace/migrations").glob("*.sql"))]
    for sql in [sql for _, _, sql in migrations()] + stage_sql:
        # What a DuckLake table cannot have is gone from the DDL (what it keeps: the columns
        # below, as the file has them).
        ddl = without_comments(lake_ddl(sql))
        assert not re.search(r"PRIMARY KEY|\bCHECK\s*\(|\w\[\d+\]|DEFAULT\s+\[", ddl, re.I), ddl

    with registered(PACE):  # a stage bringing its own tables: its migrations apply too
        with connect(tmp_path / "ringside.duckdb") as con:
            in_file = tables(con)
        with connect(lake) as con:
            in_lake = tables(con)
            versions = con.execute("SELECT version FROM schema_migrations ORDER BY 1").fetchall()
            staged = con.execute("SELECT stage, version FROM stage_migrations").fetchall()
    assert versions == [(version,) for version, _, _ in migrations()]
    assert staged == [("pace", 1)]
    assert "pace_speeds" in in_lake

    assert sorted(in_lake) == sorted(in_file)
    changed = []
    for table, file_columns in in_file.items():
        lake_columns = in_lake[table]
        assert [c[0] for c in lake_columns] == [c[0] for c in file_columns], table
        for (name, file_type, file_null), (_, lake_type, lake_null) in zip(
            file_columns, lake_columns, strict=True
        ):
            assert lake_null == file_null, f"{table}.{name}: nullable {file_null} -> {lake_null}"
            if lake_type != file_type:
                # The one difference allowed: FLOAT[N] (DOUBLE[N]) became FLOAT[] (DOUBLE[]).
                assert re.fullmatch(r"\w+\[\d+\]", file_type), f"{table}.{name}: {file_type}"
                assert lake_type == re.sub(r"\[\d+\]$", "[]", file_type), f"{table}.{name}"
                changed.append(f"{table}.{name}")
    fixed = [
        f"{table}.{name}"
        for table, columns in in_file.items()
        for name, kind, _ in columns
        if re.search(r"\[\d+\]", kind)
    ]
    assert changed == fixed and len(fixed) > 10  # every fixed-size array, and there are many


def test_a_lake_connection_draws_no_progress_bar(lake: Lake):
    # DuckDB draws one on stdout, piped or not, for a query past 2 s (which a catalog's queries
    # reach on a loaded machine): in a command's JSON, in what a parent reads off a child. (No
    # query here runs that long; setting `progress_bar_time` to provoke one turns it back on.)
    con = _open_lake(lake, read_only=False, wait_s=10)
    try:
        assert con.execute("SELECT current_setting('enable_progress_bar')").fetchone() == (False,)
    finally:
        con.close()


# -- Outputs as the tests write them ----------------------------------------------------------

# What every child process below starts with: ``lake`` from its first two arguments, and
# `commit`, which writes output ``i`` of writer ``worker`` for ``video`` (n `ingest_shots` rows
# and two metrics) and returns how many attempts it took: write_output reads its ``rows`` once
# per attempt, and `transact` runs the transaction again after a conflict.
CHILD = """
import itertools, json, sys, time
from collections.abc import Mapping
from pathlib import Path
import numpy as np
from storage.db import connect, error_line
from storage.paths import Lake
from storage.records import OutputRecord, write_output

class Counted(Mapping):
    def __init__(self, rows):
        self.rows, self.reads = rows, 0
    def __getitem__(self, name):
        return self.rows[name]
    def __iter__(self):
        return iter(self.rows)
    def __len__(self):
        return len(self.rows)
    def items(self):
        self.reads += 1
        return self.rows.items()

def commit(con, video, worker, i, n):
    shots = np.arange(n)
    rows = Counted({"ingest_shots": {
        "shot": shots.astype(np.int32), "start_frame": shots * 10, "end_frame": shots * 10 + 10,
        "cut_distance": np.full(n, 0.5),
        "thumbnail": np.array([f"{worker}/{i}/{j}" for j in range(n)]),
    }})
    config = {"worker": worker, "i": i, "n": n}
    record = OutputRecord("ingest", video, "k", config, "test", {}, f"run-{worker}", 1.0)
    write_output(con, record, rows, {"shots": float(n), "worker": float(worker)})
    return rows.reads

lake = Lake(sys.argv[1], Path(sys.argv[2]))
args = sys.argv[3:]
"""


def commit(con: duckdb.DuckDBPyConnection, video: str, worker: int, i: int, n: int) -> None:
    """CHILD's `commit`, from this process."""
    shots = np.arange(n)
    columns = {
        "shot": shots.astype(np.int32),
        "start_frame": shots * 10,
        "end_frame": shots * 10 + 10,
        "cut_distance": np.full(n, 0.5),
        "thumbnail": np.array([f"{worker}/{i}/{j}" for j in range(n)]),
    }
    config = {"worker": worker, "i": i, "n": n}
    record = OutputRecord("ingest", video, "k", config, "test", {}, f"run-{worker}", 1.0)
    write_output(
        con, record, {"ingest_shots": columns}, {"shots": float(n), "worker": float(worker)}
    )


def output_contents(con: duckdb.DuckDBPyConnection, at: str = "") -> dict[str, dict]:
    """Per ingest output (by video): its stage_outputs rows' configs, its shots' thumbnails
    and its metrics, as of snapshot ``at`` (`AT (VERSION => n)`) or now, all three read in one
    transaction: a writer committing between two reads made one output look mixed (a config
    and shots of one commit beside the metrics of the next) in what was read, not in the lake."""
    con.begin()
    try:
        return _contents(con, at)
    finally:
        con.rollback()


def _contents(con: duckdb.DuckDBPyConnection, at: str) -> dict[str, dict]:
    found: dict[str, dict] = {}

    def entry(video: str) -> dict:
        return found.setdefault(video, {"configs": [], "thumbnails": [], "metrics": {}})

    for video, config in con.execute(
        f"SELECT video_id, config FROM stage_outputs {at} WHERE stage = 'ingest'"
    ).fetchall():
        entry(video)["configs"].append(json.loads(config))
    for video, thumbnail in con.execute(
        f"SELECT video_id, thumbnail FROM ingest_shots {at} ORDER BY video_id, shot"
    ).fetchall():
        entry(video)["thumbnails"].append(thumbnail)
    for video, name, value in con.execute(
        f"SELECT video_id, name, value FROM stage_metrics {at} WHERE stage = 'ingest'"
    ).fetchall():
        metrics = entry(video)["metrics"]
        assert name not in metrics, f"{video}: metric {name} twice"
        metrics[name] = value
    return found


def whole(video: str, content: dict) -> None:
    """``content`` (an `output_contents` entry) is one whole output as `commit` writes it: one
    stage_outputs row, exactly its shots, once each, and its metrics."""
    assert len(content["configs"]) == 1, f"{video}: {len(content['configs'])} stage_outputs rows"
    worker, i, n = (content["configs"][0][name] for name in ("worker", "i", "n"))
    assert content["thumbnails"] == [f"{worker}/{i}/{j}" for j in range(n)], video
    assert content["metrics"] == {"shots": n, "worker": worker}, video


def newest_snapshot(con: duckdb.DuckDBPyConnection) -> int:
    return con.execute("SELECT max(snapshot_id) FROM ducklake_snapshots('results')").fetchone()[0]


# -- 2. Many writers at once -----------------------------------------------------------------

# Connects, says "ready", waits for a line, then commits ``count`` outputs (``same``: all of
# one video, each replacing the one before), and prints each commit's attempts and seconds.
WRITER = (
    CHILD
    + """
worker, count, same = int(args[0]), int(args[1]), args[2] == "same"
with connect(lake) as con:
    print("ready", flush=True)
    sys.stdin.readline()
    attempts, seconds = [], []
    for i in range(count):
        start = time.monotonic()
        video = "same" if same else f"w{worker}-{i}"
        attempts.append(commit(con, video, worker, i, 1 + (worker * 7 + i) % 9))
        seconds.append(time.monotonic() - start)
print(json.dumps({"attempts": attempts, "seconds": seconds}), flush=True)
"""
)


def start_writers(spawn, lake: Lake, workers: int, count: int, same: bool) -> list[Child]:
    return [
        spawn(WRITER, lake.catalog, lake.shared, w, count, "same" if same else "own")
        for w in range(workers)
    ]


def run_writers(children: list[Child]) -> tuple[list[dict], float]:
    """WRITER processes let go at once, when all are connected: what each reported, and the
    seconds from then until the last was done."""
    for child in children:
        assert child.line(60) == "ready"
    started = time.monotonic()
    for child in children:
        child.send("go")
    reports = [json.loads(child.line(120)) for child in children]
    wall = time.monotonic() - started
    for child in children:
        assert child.process.wait(30) == 0, child.said()
    return reports, wall


def test_many_writer_processes_commit_every_output_once(spawn, lake: Lake):
    with connect(lake) as con:  # migrated once here, not by four processes at once
        commit(con, "same", 9, 0, 1)  # the output the second part's writers replace
        first = newest_snapshot(con)
    rolled = rolled_back(lake)

    reports, wall = run_writers(start_writers(spawn, lake, workers=4, count=12, same=False))
    replacing = start_writers(spawn, lake, workers=2, count=12, same=True)  # for the second part
    retried = sum(a - 1 for r in reports for a in r["attempts"])
    internal = rolled_back(lake) - rolled
    with connect(lake, read_only=True) as con:
        found = output_contents(con)
        runs = con.execute(
            "SELECT video_id, count(*) FROM stage_runs WHERE stage = 'ingest' GROUP BY ALL"
        ).fetchall()
        last = newest_snapshot(con)
        # Not only at the end: at five snapshots between, every output there is whole.
        for snapshot in np.linspace(first, last, 5).round().astype(int):
            for video, content in output_contents(con, f"AT (VERSION => {snapshot})").items():
                whole(video, content)
    videos = {f"w{w}-{i}" for w in range(4) for i in range(12)}
    assert set(found) == videos | {"same"}
    for video in videos:
        whole(video, found[video])
        assert found[video]["configs"][0]["worker"] == int(video[1])
    assert dict(runs) == dict.fromkeys(videos, 1) | {"same": 1}
    seconds = [s for r in reports for s in r["seconds"]]
    print(
        f"\n4 writers x 12 outputs in {wall:.1f} s: {retried} conflicts retried by transact, "
        f"{internal} PostgreSQL rollbacks in the catalog (DuckLake's own commit retries); "
        f"commit {summary(seconds)}"
    )

    # Two processes replacing one output (DELETE + INSERT of one key) over and over: each
    # deletes the rows the other may be deleting too, DuckLake refuses the second commit, and
    # `transact` runs it again on the rows the first left.
    rolled = rolled_back(lake)
    reports, wall = run_writers(replacing)
    retried = sum(a - 1 for r in reports for a in r["attempts"])
    internal = rolled_back(lake) - rolled
    with connect(lake, read_only=True) as con:
        whole("same", output_contents(con)["same"])
        snapshots = range(last, newest_snapshot(con) + 1)
        for snapshot in snapshots:  # in every snapshot the two made: one copy, whole
            at = f"AT (VERSION => {snapshot})"
            # Two tables, not output_contents' three: each table read at a snapshot asks the
            # catalog for its files then (~70 ms here).
            (configs, shots) = con.execute(
                f"SELECT list(config::VARCHAR), (SELECT list(thumbnail ORDER BY shot) FROM "
                f"ingest_shots {at} WHERE video_id = 'same') FROM stage_outputs {at} "
                "WHERE stage = 'ingest' AND video_id = 'same'"
            ).fetchone()
            assert len(configs) == 1, (snapshot, configs)
            worker, i, n = (json.loads(configs[0])[name] for name in ("worker", "i", "n"))
            assert shots == [f"{worker}/{i}/{j}" for j in range(n)], snapshot
    seconds = [s for r in reports for s in r["seconds"]]
    print(
        f"2 writers x 12 replacements of one output in {wall:.1f} s: {retried} conflicts "
        f"retried by transact, {internal} PostgreSQL rollbacks; commit {summary(seconds)}; "
        f"one whole copy in each of {len(snapshots)} snapshots"
    )
    assert retried > 0, "the two writers never collided: this part tested nothing"


# Waits for a line, then opens the lake for writing (attaching it, which creates the catalog's
# own tables when none are there yet, and migrating it) and prints the schema's versions.
OPENER = (
    CHILD
    + """
print("ready", flush=True)
sys.stdin.readline()
with connect(lake) as con:
    rows = con.execute("SELECT version FROM schema_migrations ORDER BY version").fetchall()
    print(json.dumps([version for (version,) in rows]), flush=True)
"""
)


def test_many_processes_opening_a_fresh_lake_at_once_all_get_it(spawn, lake: Lake):
    # The first connections of a team's workers meet a catalog database with nothing in it: each
    # DuckLake attach creates the catalog's tables, and all but one of them find those tables
    # made meanwhile ("relation ... already exists"; CI saw it on three workers).
    children = [spawn(OPENER, lake.catalog, lake.shared) for _ in range(6)]
    for child in children:
        assert child.line(60) == "ready"
    for child in children:
        child.send("go")
    versions = [version for version, _, _ in migrations()]
    for child in children:
        assert json.loads(child.line(120)) == versions, child.said()
        assert child.process.wait(30) == 0, child.said()
    with connect(lake, read_only=True) as con:
        applied = con.execute("SELECT version FROM schema_migrations ORDER BY 1").fetchall()
    assert applied == [(version,) for version in versions]  # each migration applied once


# Waits for a line, then opens the lake to read as soon as it exists (a dashboard or a
# scheduled run's first look) and prints the schema's versions.
READER = (
    CHILD
    + """
print("ready", flush=True)
sys.stdin.readline()
while not lake.exists():
    time.sleep(0.001)
with connect(lake, read_only=True) as con:
    rows = con.execute("SELECT version FROM schema_migrations ORDER BY version").fetchall()
    print(json.dumps([version for (version,) in rows]), flush=True)
"""
)


def test_a_reader_that_sees_a_fresh_lake_exist_can_open_it(
    spawn, postgres_port: int, tmp_path: Path
):
    # A lake exists for a reader once a writer's first attach has made its catalog: CI saw a
    # scheduled run's reader attach in the moment between the writer making the data folder and
    # its catalog committing ("Existing DuckLake ... does not exist").
    for attempt in range(3):
        lake = new_lake(postgres_port, tmp_path / f"shared-{attempt}")
        readers = [spawn(READER, lake.catalog, lake.shared) for _ in range(4)]
        writer = spawn(OPENER, lake.catalog, lake.shared)
        for child in [*readers, writer]:
            assert child.line(60) == "ready"
        for child in [*readers, writer]:
            child.send("go")
        versions = [version for version, _, _ in migrations()]
        for child in [writer, *readers]:
            assert json.loads(child.line(120)) == versions, child.said()
            assert child.process.wait(30) == 0, child.said()


# -- 3. Claims across machines ---------------------------------------------------------------

CLAIM = (
    CHILD
    + """
from storage.claims import lake_claimed

with lake_claimed(lake, "ingest", "v", "k", lambda h: print("waiting", h, flush=True)) as waited:
    print("holding", waited, flush=True)
    time.sleep(600)
"""
)


def test_a_lake_claim_waits_for_its_holder_and_passes_on_when_it_is_killed(spawn, lake: Lake):
    first = spawn(CLAIM, lake.catalog, lake.shared)
    assert first.line(60) == "holding False"
    second = spawn(CLAIM, lake.catalog, lake.shared)
    assert second.line(60) == f"waiting {socket.gethostname()}:{first.pid}"
    assert second.quiet_for(1.5) is None  # it waits while the first holds the claim

    first.process.send_signal(signal.SIGKILL)
    killed = time.monotonic()
    first.process.wait()
    assert second.line(10) == "holding True"
    passed = time.monotonic() - killed
    assert passed < 5.0
    print(f"\nthe claim passed on {passed:.2f} s after its holder was killed")

    second.kill()
    with lake_claimed(lake, "ingest", "v", "k") as waited:  # the second's claim went with it
        assert not waited
        with lake_claimed(lake, "ingest", "v", "other") as waited_other:
            assert not waited_other  # another output's claim is another lock


# -- 4. SIGKILL in the middle of a commit ----------------------------------------------------

# Connects, says "ready", then commits large outputs in a loop: its output i replaces video
# big-(i % 3)'s with ROWS + (i * 977) % 1500 shots. It prints each commit as it returns.
BIG_ROWS = 3000
BIG_WRITER = (
    CHILD
    + """
worker, rows = int(args[0]), int(args[1])
with connect(lake) as con:
    print("ready", flush=True)
    for i in itertools.count():
        commit(con, f"big-{i % 3}", worker, i, rows + (i * 977) % 1500)
        print("committed", i, flush=True)
"""
)


def test_sigkill_mid_commit_leaves_each_output_whole_or_absent(spawn, lake: Lake):
    with connect(lake):  # migrated here, not in the first round's time
        pass
    seed = random.randrange(2**32)
    rng = random.Random(seed)
    rounds = []
    writer = spawn(BIG_WRITER, lake.catalog, lake.shared, 0, BIG_ROWS)
    for round_ in range(3):
        assert writer.line(60) == "ready"
        delay = rng.uniform(0.2, 1.5)
        time.sleep(delay)
        writer.process.send_signal(signal.SIGKILL)
        writer.process.wait()
        said = []
        while (line := writer.quiet_for(0.1)) not in (None, "<ended>"):
            said.append(line)
        assert writer.process.returncode == -signal.SIGKILL, writer.said()
        if round_ < 4:  # the next round's writer starts while this one's outputs are checked
            writer = spawn(BIG_WRITER, lake.catalog, lake.shared, round_ + 1, BIG_ROWS)
        # A fresh writer after the kill: what it reads is whole, and its own commit lands.
        with connect(lake) as con:
            found = output_contents(con)
            for video, content in found.items():
                assert video in {"big-0", "big-1", "big-2"} | {f"after-{r}" for r in range(3)}
                whole(video, content)
            commit(con, f"after-{round_}", 99, round_, 2)
            whole(f"after-{round_}", output_contents(con)[f"after-{round_}"])
        committed = [int(line.split()[1]) for line in said if line.startswith("committed")]
        # Each video's output is the last the killed writer said it committed, or newer (one it
        # committed before the kill came but did not say yet, or the next round's writer's).
        for video in ("big-0", "big-1", "big-2"):
            mine = [i for i in committed if f"big-{i % 3}" == video]
            if mine:
                assert video in found, (seed, video, "committed, then gone")
                config = found[video]["configs"][0]
                assert (config["worker"], config["i"]) >= (round_, max(mine)), (seed, video)
        rounds.append((round(delay, 2), len(committed)))
    with connect(lake, read_only=True) as con:
        (orphans,) = con.execute(
            "SELECT count(*) FROM ducklake_delete_orphaned_files('results', dry_run => true, "
            "cleanup_all => true)"
        ).fetchone()
    print(
        f"\nkill rounds (seed {seed}; delay s, commits said): {rounds}; {orphans} data files "
        "written by killed commits and never committed"
    )


# -- 5. PostgreSQL restarted mid-run ---------------------------------------------------------

# Says "started" and waits for a line. "late" then says "connecting", connects (waiting while
# PostgreSQL does not answer) and commits one output. "held" connects, says "ready", and on a
# line commits one output on that connection, then another. Each commit's outcome is a JSON
# line: its seconds and attempts, or its error as `error_line` gives it.
RESTART = (
    CHILD
    + """
def attempt(con, video, worker):
    start = time.monotonic()
    try:
        attempts = commit(con, video, worker, 0, 3)
    except Exception as error:
        return {"video": video, "error": f"{type(error).__name__}: {error_line(error)}",
                "seconds": time.monotonic() - start}
    return {"video": video, "attempts": attempts, "seconds": time.monotonic() - start}

print("started", flush=True)
sys.stdin.readline()
if args[0] == "late":
    print("connecting", flush=True)
    start = time.monotonic()
    with connect(lake) as con:
        waited = time.monotonic() - start
        print(json.dumps({**attempt(con, "late", 1), "connect_s": waited}), flush=True)
else:
    with connect(lake) as con:
        print("ready", flush=True)
        sys.stdin.readline()
        print(json.dumps(attempt(con, "held", 2)), flush=True)
        print(json.dumps(attempt(con, "held-again", 3)), flush=True)
"""
)


def test_a_run_waits_for_postgresql_through_a_restart(spawn, tmp_path: Path):
    # A cluster of this test's own, stopped and started. Not under tmp_path: as root, the
    # server runs as `postgres`, who cannot reach pytest's folders (mode 700).
    folder = Path(tempfile.mkdtemp(prefix="ringside-lake-restart-"))
    port = start_cluster(folder)
    cluster = folder / "postgres"
    try:
        lake = new_lake(port, tmp_path / "shared")
        held = spawn(RESTART, lake.catalog, lake.shared, "held")
        late = spawn(RESTART, lake.catalog, lake.shared, "late")
        with connect(lake):  # migrated before the restart, while they start
            pass
        assert held.line(60) == "started" and late.line(60) == "started"
        held.send("connect")
        assert held.line(60) == "ready"

        flows.postgres.stop(cluster)
        late.send("connect")
        assert late.line(10) == "connecting"
        down_s = 2.0
        assert late.quiet_for(down_s) is None  # waiting for PostgreSQL, not failing
        restarted = time.monotonic()
        flows.postgres.start(cluster, port)
        up_s = time.monotonic() - restarted
        landed = json.loads(late.line(60))
        assert "error" not in landed, landed
        assert late.process.wait(30) == 0, late.said()

        # A connection opened before the restart: PostgreSQL closed its connections under it.
        # Its first transaction fails and is rolled back whole, and `transact` runs it again
        # once DuckDB's postgres extension has connected again: it lands, run more than once.
        held.send("commit")
        first, second = json.loads(held.line(60)), json.loads(held.line(60))
        assert held.process.wait(30) == 0, held.said()
        with connect(lake, read_only=True) as con:
            found = output_contents(con)
        whole("late", found["late"])
        assert "error" not in first and first["attempts"] >= 2, first
        whole(first["video"], found[first["video"]])
        assert "error" not in second, second
        whole(second["video"], found[second["video"]])
        print(
            f"\nPostgreSQL down {down_s:.1f} s (+{up_s:.1f} s to start): connect waited "
            f"{landed['connect_s']:.1f} s, then committed in {landed['seconds']:.2f} s; a "
            f"connection open across the restart: {first}, then {second}"
        )

        # Left down: a connection is refused after its wait, in one line.
        flows.postgres.stop(cluster)
        start = time.monotonic()
        with pytest.raises(CatalogUnreachable) as refused, connect(lake, wait_s=2):
            pass
        waited = time.monotonic() - start
        message = str(refused.value)
        assert "\n" not in message and "PostgreSQL did not answer for 2 s" in message, message
        assert 2.0 <= waited < 10.0
        print(f"down: CatalogUnreachable after {waited:.1f} s: {message}")
    finally:
        stop_cluster(folder)
        shutil.rmtree(folder, ignore_errors=True)
