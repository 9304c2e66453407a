"""The dashboard keeps working while a pipeline run writes to the same database (issue 9).

A real `ringside rerun lift` runs as a subprocess on a copy of the sample's data directory while
this process renders every dashboard page again and again, as Streamlit would for an analyst
pressing Reload. DuckDB lets one process write at a time, so the pages and the pipeline take
turns with the file's lock: neither side may fail or give up waiting.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from datetime import datetime

from conftest import REPO, copy_data, query, render_page

from dashboards.app import PAGES
from dashboards.widgets import READ_AT
from storage.db import utcnow

# What a page says when it waited for the pipeline in vain (`dashboards.widgets.read`).
GAVE_UP = "held the database"
# The writer must end well within the test's time; beyond this it is stuck, not slow.
WRITER_LIMIT_S = 240.0
# Rounds of every page that must finish while the writer runs.
MIN_ROUNDS = 3


def _render_round(done: list[dict], problems: list[str]) -> None:
    """Every page once, each noted in ``done``; what went wrong, in ``problems``."""
    from streamlit.testing.v1 import AppTest

    for path in PAGES:
        start = time.perf_counter()
        began = utcnow()
        app = AppTest.from_function(render_page, args=(path,), default_timeout=60).run()
        seconds = time.perf_counter() - start
        done.append({"page": path, "began": began, "ended": utcnow(), "seconds": seconds})
        if app.exception:
            problems.append(f"{path}: exception {[e.message for e in app.exception]}")
        if app.error:
            problems.append(f"{path}: error {[e.value for e in app.error]}")
        waited = [w.value for w in app.warning if GAVE_UP in w.value]
        if waited:
            problems.append(f"{path}: {waited}")
        if not any(c.value.startswith(READ_AT) for c in app.caption):
            problems.append(f"{path}: no '{READ_AT}' caption; captions {app.caption}")


def test_every_page_renders_while_the_pipeline_writes(sample_run, tmp_path, monkeypatch):
    data = tmp_path / "data"
    copy_data(sample_run, data)
    (video_id,) = query(data, "SELECT video_id FROM videos")[0]
    monkeypatch.setenv("RINGSIDE_DATA", str(data))

    env = dict(os.environ)
    # A Prefect home of the writer's own: this process's ephemeral server keeps its own.
    env["PREFECT_HOME"] = str(tmp_path / "prefect")
    env.pop("PREFECT_API_URL", None)
    # The fixture's chunking, so only lift is recomputed (and whatever follows, if its key moved).
    command = [
        sys.executable,
        "-m",
        "flows.cli",
        "--data",
        str(data),
        "rerun",
        "lift",
        "--video",
        video_id[:12],
        "--until",
        "dataset",
        "--ingest-chunk-frames",
        "30",
    ]
    log = tmp_path / "writer.log"
    started = utcnow()
    with log.open("w") as out:
        writer = subprocess.Popen(command, cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT)
    renders: list[dict] = []
    problems: list[str] = []
    rounds_while_writing = 0
    deadline = time.monotonic() + WRITER_LIMIT_S
    try:
        while writer.poll() is None and time.monotonic() < deadline:
            _render_round(renders, problems)
            if writer.poll() is None:
                rounds_while_writing += 1
    finally:
        if writer.poll() is None:
            writer.kill()
        writer.wait()
    said = log.read_text()
    assert writer.returncode == 0, f"the pipeline run failed:\n{said[-4000:]}"
    assert not problems, "\n".join(problems)

    # The rerun committed a new lift output (and noted its run) while the pages were read.
    ((committed_at,),) = query(
        data,
        "SELECT max(created_at) FROM stage_outputs WHERE stage = 'lift' AND video_id = ?",
        [video_id],
    )
    assert committed_at > started, "the rerun wrote no new lift output"
    done = query(
        data,
        "SELECT count(*) FROM stage_runs WHERE stage = 'lift' AND video_id = ? "
        "AND state = 'done' AND created_at > ?",
        [video_id, started],
    )
    assert done == [(1,)], done
    assert rounds_while_writing >= MIN_ROUNDS, f"{rounds_while_writing} rounds: {renders}"
    before: list[datetime] = [r["ended"] for r in renders if r["ended"] < committed_at]
    after = [r["began"] for r in renders if r["began"] > committed_at]
    assert before and after, f"no page rendered on both sides of the commit at {committed_at}"
    slowest = max(renders, key=lambda r: r["seconds"])
    print(
        f"{len(renders)} renders in {rounds_while_writing} rounds while the pipeline wrote; "
        f"slowest: {slowest['page']} in {slowest['seconds']:.2f} s"
    )
