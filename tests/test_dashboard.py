"""The analysts' dashboard: its queries against what the CLI prints, every page in headless
Chromium on the sample's data, and every page of an empty data directory.

The browser test saves a full-page screenshot of each page under
``data/test-artifacts/dashboard/`` (git-ignored), to be looked at by eye.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import (
    REPO,
    TINY_EVALUATE,
    TINY_EVALUATE_FLAGS,
    TINY_TRAIN,
    TINY_TRAIN_FLAGS,
    copy_data,
    query,
    render_page,
    run_cli,
    toml,
)

from dashboards import queries
from dashboards.app import PAGES
from dashboards.opponent import EVALUATION_TILES, HEADLINES, TILES, sample_size
from dashboards.widgets import READ_AT, format_value, output_labels, video_labels
from flows.cli import build_parser, main
from flows.cli.servers import wait_until_serving
from flows.launch import run_progress, served_api
from storage.db import connect
from storage.paths import data_paths
from tasks.dataset.statistics import combine_videos
from tasks.registry import per_video

CHROMIUM = Path("/usr/bin/chromium")
SCREENSHOTS = REPO / "data" / "test-artifacts" / "dashboard"
# A page is drawn once Streamlit has written the page's last line, every chart has its canvas
# and the page's height has stopped changing between two polls.
SETTLED = """() => {
  const main = document.querySelector('[data-testid="stMain"]');
  const charts = [...document.querySelectorAll('[data-testid="stVegaLiteChart"]')];
  const drawn = charts.every(chart => chart.querySelector('canvas, svg'));
  const height = main ? main.scrollHeight : 0;
  const steady = window.__ringsideHeight === height;
  window.__ringsideHeight = height;
  return drawn && steady && height;
}"""
# Every table of the page: tables -> rows -> cell texts.
TABLES = """() => [...document.querySelectorAll('[data-testid="stTable"] table')].map(
  table => [...table.rows].map(row => [...row.cells].map(cell => cell.innerText.trim())))"""
# Every headline number of the page: [label, value].
TILE_TEXTS = """() => [...document.querySelectorAll('[data-testid="stMetric"]')].map(m => [
  m.querySelector('[data-testid="stMetricLabel"]').innerText.trim(),
  m.querySelector('[data-testid="stMetricValue"]').innerText.trim()])"""


@pytest.fixture(scope="module")
def trained(sample_run: Path, sample_dataset: str) -> tuple[Path, str]:
    """The sample's data directory with a tiny training run on its first dataset (three
    iterations: not the two `test_train_stage` trains, so both tests find their run new),
    evaluated."""
    dataset_key = sample_dataset
    argv = ["--data", str(sample_run), "train", "--dataset", dataset_key, *TINY_TRAIN_FLAGS]
    said = io.StringIO()
    with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
        code = main([*argv, "--train-iterations", "3", "--json"])
    assert code == 0, said.getvalue()
    (run,) = json.loads(said.getvalue().splitlines()[-1])
    said = io.StringIO()
    with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
        code = main(
            ["--data", str(sample_run), "evaluate", "--run", run["key"], *TINY_EVALUATE_FLAGS]
        )
    assert code == 0, said.getvalue()
    return sample_run, dataset_key


def _cli_json(capsys, data: Path, *argv: str) -> list[dict]:
    code, out, err = run_cli(capsys, "--data", str(data), *argv, "--json")
    assert code == 0, err
    return json.loads(out)


def _read(data: Path, read_with):
    with connect(data_paths(data).db, read_only=True) as con:
        return read_with(con)


def _newest_run(data: Path, dataset_key: str) -> dict:
    runs = _read(data, queries.training_runs)
    return next(r for r in runs if r["dataset_key"] == dataset_key and r["iterations"] == 3)


def test_the_dashboards_queries_import_no_model_runtime():
    """The dashboard reads stores and storage only: importing its queries loads no torch, MuJoCo,
    LiteRT or OpenCV (it loaded all four, 2.2 s warm, before the stores owned their SQL)."""
    heavy = ("torch", "mujoco", "ai_edge_litert", "cv2")
    code = f"import sys, dashboards.queries; print([m for m in {heavy!r} if m in sys.modules])"
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        cwd=Path(__file__).parents[1],
    ).stdout
    assert out.strip() == "[]", out


def test_the_stages_page_knows_the_stages_the_cli_does():
    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    (stage,) = [a for a in commands.choices["metrics"]._actions if a.dest == "stage"]
    assert tuple(stage.choices) == queries.metric_stages()


def test_metrics_are_the_ones_the_cli_prints(capsys, trained):
    data, _ = trained
    for stage in queries.metric_stages():
        printed = _cli_json(capsys, data, "metrics", "--stage", stage)
        if stage in (*per_video(), "train"):  # the sample went through these; not evaluation
            assert printed, f"the sample has no {stage} metrics"
        table = queries.metrics_table(
            _read(data, lambda con, s=stage: queries.stage_metrics(con, s))
        )
        shown = {
            (output, name): value
            for output, column in table.items()
            for name, value in column.items()
            if not math.isnan(value)
        }
        assert shown == {(r["video_id"], r["name"]): r["value"] for r in printed}, stage


def test_overview_shows_the_sample_with_every_stage_done(capsys, trained, sample_video):
    data, _ = trained
    videos, states = _read(data, lambda con: (queries.videos(con), queries.stage_overview(con)))
    fields = ("video_id", "stage", "key", "state", "error")
    opponents = _read(data, queries.opponent_overview)
    shown = [{f: r[f] for f in fields} for r in [*states, *opponents]]
    assert shown == _cli_json(capsys, data, "status")
    assert any(r["stage"] == "train" for r in opponents), "the fixture's training is listed"
    (sample,) = [v for v in videos if v["path"] == str(sample_video)]
    assert sample["adversary"] == "A"
    matrix = queries.state_matrix(states)
    assert list(matrix.columns) == list(per_video())
    assert set(matrix.loc[sample["video_id"]]) <= {"done", "cached"}
    done = [r for r in states if r["video_id"] == sample["video_id"]]
    assert all(r["seconds"] > 0 and r["ran_at"] is not None for r in done)


def test_learning_curves_are_the_ones_the_cli_prints(capsys, trained):
    data, dataset_key = trained
    run = _newest_run(data, dataset_key)
    assert run["state"] == "finished" and run["adversary"] == "A"
    every = queries.default_every(run["iterations"])
    printed = _cli_json(capsys, data, "curves", "--run", run["key"], "--every", str(every))
    rows = _read(data, lambda con: queries.curves(con, run["key"], every=every))
    assert rows == printed
    frame = queries.curves_frame(rows)
    assert list(frame.index) == list(range(0, run["iterations"], every))


def test_statistics_of_several_videos_weigh_each_by_its_minutes():
    scalars = [
        ("a", "adversary", "minutes", 1.0),
        ("a", "adversary", "punches_per_min", 10.0),
        ("b", "adversary", "minutes", 3.0),
        ("b", "adversary", "punches_per_min", 2.0),
        ("b", "opponent", "minutes", 3.0),
    ]
    samples = [
        ("a", "adversary", "punch_duration_s", [0.2, 0.4]),
        ("b", "adversary", "punch_duration_s", [0.6]),
    ]
    combined = combine_videos(scalars, samples)
    assert set(combined) == {"adversary", "opponent"}
    adversary = combined["adversary"].scalars
    assert adversary["minutes"] == 4.0
    assert adversary["punches_per_min"] == pytest.approx((10 * 1 + 2 * 3) / 4)
    # A per-punch mean weighs punches, not minutes.
    assert adversary["punch_duration_mean_s"] == pytest.approx(0.4)
    assert list(combined["adversary"].distributions["punch_duration_s"]) == [0.2, 0.4, 0.6]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cell(tables: list, row_name: str, column: str) -> str:
    """The text of the cell in row ``row_name`` (its first cell) and column ``column`` (a header
    cell) of the first table that has both."""
    for rows in tables:
        header = next((row for row in rows if column in row), None)
        found = [row for row in rows if row and row[0] == row_name]
        if header is not None and found:
            return found[0][header.index(column)]
    raise AssertionError(f"no table has row {row_name!r} and column {column!r}")


def _settle(page) -> int:
    """Wait until the page is drawn; its height."""
    # The first render of a fresh server imports the pipeline's modules: allow for it.
    page.get_by_text(READ_AT).wait_for(timeout=120_000)
    return page.wait_for_function(SETTLED, polling=250, timeout=60_000).json_value()


def _open(page, url: str, shot: str) -> str:
    """Open ``url``, wait until the page is drawn, save its screenshot; the page's text."""
    page.set_viewport_size({"width": 1400, "height": 900})
    page.goto(url)
    height = _settle(page)
    # Streamlit scrolls inside its main block, so a full-page screenshot needs a tall window.
    page.set_viewport_size({"width": 1400, "height": int(height)})
    page.screenshot(path=str(SCREENSHOTS / f"{shot}.png"), full_page=True)
    text = page.inner_text("body")
    assert "Traceback" not in text and "Error" not in text, f"{shot}: {text[:2000]}"
    assert page.locator('[data-testid="stException"]').count() == 0, shot
    return text


def _play_videos(page, shot: str) -> int:
    """Play every video of the page, muted, to its end; how many there were."""
    videos = page.locator("video")
    for i in range(videos.count()):
        video = videos.nth(i)
        video.scroll_into_view_if_needed()
        # play() rejects when the browser cannot decode the file (OpenCV's mp4v, say).
        duration = video.evaluate("v => { v.muted = true; return v.play().then(() => v.duration) }")
        assert duration > 0, (shot, i)
        ended = video.evaluate(
            "v => new Promise(done => { if (v.ended) done(true); v.onended = () => done(true); })"
        )
        assert ended and video.evaluate("v => v.currentTime") >= duration - 0.1, (shot, i)
    return videos.count()


def _start_serving(data: Path, home: Path) -> subprocess.Popen:
    """`ringside serve` on ``data``: a Prefect server (its home ``home``, not the one this
    process's ephemeral servers share) and the runner of the pipeline's deployment. Its output
    goes to ``home/serve.log``: a pipe nobody reads could fill and stall it."""
    home.mkdir(parents=True, exist_ok=True)
    command = ["-m", "flows.cli", "--data", str(data), "serve", "--port", str(_free_port())]
    with (home / "serve.log").open("w") as log:
        return subprocess.Popen(
            [sys.executable, *command],
            env={**os.environ, "PREFECT_HOME": str(home)},
            stdout=log,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )


def _stop(process: subprocess.Popen, what: str) -> str:
    """Stop ``process`` as Ctrl-C would (SIGTERM); its output. Fails the test if it hangs."""
    process.send_signal(signal.SIGTERM)
    try:
        out, _ = process.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        out, _ = process.communicate()
        pytest.fail(f"{what} did not stop on SIGTERM:\n{out}")
    return out


@pytest.mark.skipif(
    not CHROMIUM.exists(), reason=f"Debian's chromium is not installed ({CHROMIUM}): `make setup`"
)
def test_every_page_in_a_browser(capsys, trained, tmp_path, request):
    from playwright.sync_api import sync_playwright

    # A copy: the rerun and the pick below must not change the shared sample's outputs.
    data, dataset_key = copy_data(trained[0], tmp_path / "data"), trained[1]
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    home = tmp_path / "prefect"
    serving = _start_serving(data, home)  # it takes a while to come up: meanwhile, the pages
    # Stopped however the test ends: a failure before the dashboard's `try` left it running
    # (stopping it again after the `finally` below does nothing).
    request.addfinalizer(lambda: _stop(serving, "`ringside serve`"))
    metrics = {
        stage: _cli_json(capsys, data, "metrics", "--stage", stage)
        for stage in queries.metric_stages()
    }
    videos, sets = _read(data, lambda con: (queries.videos(con), queries.datasets(con)))
    run = _newest_run(data, dataset_key)
    every = queries.default_every(run["iterations"])
    newest = _cli_json(capsys, data, "curves", "--run", run["key"], "--every", str(every))[-1]
    members = query(
        data, "SELECT video_id, key FROM dataset_members WHERE dataset_key = ?", [dataset_key]
    )
    assert len(members) == 1, "the sample's dataset joins one video"
    video_id = members[0][0]
    adversary = dict(
        query(
            data,
            "SELECT name, value FROM dataset_statistics WHERE video_id = ? AND key = ? "
            "AND role = 'adversary'",
            list(members[0]),
        )
    )
    review = _read(data, lambda con: queries.lift_review(con, video_id))
    # Each Lift tile summarises the series charted under it (before, the deepest-penetration
    # tile read 2.082e-14 mm from the stage's summary while its chart peaked at 2.6e-8 m).
    penetration = review.series[[c for c in review.series if c.startswith(queries.PENETRATION)]]
    assert review.tiles["Deepest penetration (mm)"] == penetration.max().max() * 1000
    assert all(math.isfinite(v) for v in review.tiles.values()), review.tiles
    judged = {r["name"]: r["value"] for r in metrics["evaluate"] if r["video_id"] == run["key"]}
    assert judged, "the fixture evaluated the run"

    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    command = ["-m", "flows.cli", "--data", str(data), "dashboard", "--port", str(port)]
    # The dashboard's reruns take the settings of ./ringside.toml where it was started: the
    # sample's, so that a rerun recomputes the stage asked for and finds the rest cached.
    # (The fixture's tiny training run of three iterations and its evaluation included.)
    sample = {"ingest.chunk_frames": "30", **TINY_TRAIN, "train.iterations": "3", **TINY_EVALUATE}
    (tmp_path / "ringside.toml").write_text(toml(sample))
    server = subprocess.Popen(
        [sys.executable, *command, "--no-browser"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        assert wait_until_serving(url, server, timeout_s=90), "the dashboard never answered"
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(
                executable_path=str(CHROMIUM), args=["--no-sandbox"]
            )
            page = browser.new_page()

            for stage, printed in metrics.items():
                text = _open(page, f"{url}/stages?stage={stage}", f"stage-{stage}")
                if not printed:
                    assert f"No {stage} output yet" in text
                names = output_labels(stage, [r["video_id"] for r in printed], videos, sets)
                tables = page.evaluate(TABLES)
                for row in printed:
                    cell = _cell(tables, row["name"], names[row["video_id"]])
                    assert cell == format_value(row["value"]), (stage, row)

            text = _open(page, f"{url}/pose?video={video_id}", "pose")
            assert "Which track is the adversary?" in text
            assert _play_videos(page, "pose") == 1

            _open(page, f"{url}/lift?video={video_id}", "lift")
            tiles = dict(page.evaluate(TILE_TEXTS))
            assert {label: tiles[label] for label in review.tiles} == {
                label: format_value(value) for label, value in review.tiles.items()
            }
            assert _play_videos(page, "lift") == 1

            text = _open(page, f"{url}/dataset?dataset={dataset_key}", "dataset")
            tiles = dict(page.evaluate(TILE_TEXTS))
            for name, label in HEADLINES.items():
                assert tiles[label] == format_value(adversary.get(name)), name
            # The rates say what they were measured on: the sample's 1.4 s.
            assert sample_size(adversary) in text and "Measured on 1.4 s" in text

            text = _open(page, f"{url}/training?run={run['key']}", "training")
            assert queries.short(run["key"]) in text
            tiles = dict(page.evaluate(TILE_TEXTS))
            for name, label in TILES.items():
                assert tiles[label] == format_value(newest.get(name)), name

            text = _open(page, f"{url}/evaluation?run={run['key']}", "evaluation")
            # The sample's held-out split is too short for the classifier test: the page says why.
            assert "Held-out classifier test" in text and "no held-out footage" in text
            tiles = dict(page.evaluate(TILE_TEXTS))
            for name, label in EVALUATION_TILES.items():
                assert tiles[label] == format_value(judged[name]), name
            assert _play_videos(page, "evaluation") == 1

            # The rerun button: ingest (the first stage) of the sample, through the served
            # deployment; the page follows the run to its end.
            deadline = time.monotonic() + 180
            while served_api(data_paths(data)) is None and time.monotonic() < deadline:
                assert serving.poll() is None, (home / "serve.log").read_text()
                time.sleep(1)
            assert served_api(data_paths(data)), "`ringside serve` never came up"
            text = _open(page, f"{url}/", "overview")
            # Training on the sample's dataset and the evaluation of that run, as `status` has them.
            opponents = {
                (r["stage"], r["video_id"]): r for r in _read(data, queries.opponent_overview)
            }
            assert opponents["train", dataset_key]["key"] == run["key"]
            assert opponents["train", dataset_key]["state"] in ("done", "cached")
            assert opponents["evaluate", run["key"]]["state"] in ("done", "cached")
            assert f"dataset {queries.short(dataset_key)}" in text
            assert f"run {queries.short(run['key'])}" in text
            labels = video_labels(videos)
            for state in _read(data, queries.stage_overview):
                label = labels[state["video_id"]]
                assert _cell(page.evaluate(TABLES), label, state["stage"]) == state["state"]
            before = _read(
                data,
                lambda con: con.execute("SELECT max(created_at) FROM stage_runs").fetchone()[0],
            )
            page.get_by_role("button", name="Rerun").click()
            page.get_by_text("Completed", exact=False).wait_for(timeout=300_000)
            page.screenshot(path=str(SCREENSHOTS / "overview-rerun.png"), full_page=True)
            text = page.inner_text("body")
            finished = "stages finished: ingest, pose, lift, dataset, train, evaluate"
            assert finished in text, text[-2000:]
            assert "Failed" not in text
            rerun = query(
                data,
                "SELECT run_id, state FROM stage_runs WHERE stage = 'ingest' AND video_id = ? "
                "AND created_at > ? AND state = 'done'",
                [videos[0]["video_id"], before],
            )
            assert rerun, "the ingest stage was not recomputed"
            later = query(
                data,
                "SELECT stage, state FROM stage_runs WHERE video_id = ? AND created_at > ? "
                "AND stage <> 'ingest'",
                [videos[0]["video_id"], before],
            )
            assert sorted(later) == [("dataset", "cached"), ("lift", "cached"), ("pose", "cached")]
            assert run_progress(data_paths(data), rerun[0][0]).state == "Completed"

            # The fighter pick: the other track is the adversary, the pipeline reruns from pose.
            _open(page, f"{url}/pose?video={video_id}", "pose")
            tracks = _read(data, lambda con: queries.pose_review(con, video_id).tracks)
            other = int(tracks.loc[tracks["role"] == "opponent", "track"].iloc[0])
            # Typing into the select box lists the matching choices.
            choice = page.get_by_role("combobox", name="Adversary track")
            choice.scroll_into_view_if_needed()
            choice.fill(f"track {other}")
            page.get_by_role("option", name=f"track {other} (now opponent)").click()
            page.get_by_role("button", name="Pick and rerun").click()
            page.get_by_text(f"Track {other} is the adversary now").wait_for()
            # The sidebar's links keep the browser's session, and with it the runs it follows.
            page.get_by_role("link", name="Overview").click()
            page.get_by_text(re.compile(r"Rerun of pose .*Completed")).wait_for(timeout=300_000)
            page.screenshot(path=str(SCREENSHOTS / "overview-pick.png"), full_page=True)
            assert "Failed" not in page.inner_text("body")
            browser.close()
        picked = _read(data, lambda con: queries.pose_review(con, video_id))
        assert picked.pick == other
        roles = dict(zip(picked.tracks["track"], picked.tracks["role"], strict=True))
        assert roles[other] == "adversary"
    finally:
        out = _stop(server, "the dashboard")
        _stop(serving, "`ringside serve`")
    assert server.returncode == 0, out
    assert serving.returncode == 0, (home / "serve.log").read_text()
    assert "dashboard stopped" in out and f"http://localhost:{port}" in out
    with socket.socket() as s:  # nothing listens any more
        assert s.connect_ex(("127.0.0.1", port)) != 0


@pytest.mark.parametrize(
    ("path", "message"),
    [
        ("overview", "No video yet"),
        ("stages", "No ingest output yet"),
        ("dataset", "No dataset yet"),
        ("training", "No training run yet: run `ringside train --dataset KEY`"),
    ],
)
def test_pages_of_an_empty_data_directory(tmp_path, monkeypatch, path, message):
    from streamlit.testing.v1 import AppTest

    assert path in PAGES
    monkeypatch.setenv("RINGSIDE_DATA", str(tmp_path))
    app = AppTest.from_function(render_page, args=(path,), default_timeout=60)
    assert [i.value for i in app.run().info] == [
        f"No database yet in `{tmp_path}`: run `ringside process VIDEO --adversary NAME` "
        "(or `ringside demo`)."
    ]
    with connect(data_paths(tmp_path).db):
        pass  # a fresh database: every table there, all of them empty
    app = AppTest.from_function(render_page, args=(path,), default_timeout=60).run()
    assert not app.exception, app.exception
    (info,) = app.info
    assert info.value.startswith(message), info.value
    assert not app.error and not app.warning


def test_a_failed_stage_shows_why_on_the_overview(tmp_path, monkeypatch):
    from streamlit.testing.v1 import AppTest

    from storage.records import record_run, register_video

    why = "pose: no fighters found in /footage/empty.mp4"
    with connect(data_paths(tmp_path).db) as con:
        register_video(con, "f" * 64, 1234, "/footage/empty.mp4")
        record_run(con, "run-1", "f" * 64, "pose", "k" * 24, "failed", why)
    monkeypatch.setenv("RINGSIDE_DATA", str(tmp_path))
    app = AppTest.from_function(render_page, args=("overview",), default_timeout=60).run()
    assert not app.exception, app.exception
    matrix, runs = (table.value for table in app.table)
    states = ["failed" if stage == "pose" else "missing" for stage in per_video()]
    assert list(matrix.loc[f"empty.mp4 · {'f' * 12}", list(per_video())]) == states
    assert list(runs["why it failed"]) == [why if s == "failed" else "" for s in states]


def show_artifact(name: str) -> None:
    """A script for AppTest: where `artifact_file` finds the artifact ``name``, if it serves it."""
    import streamlit as st

    from dashboards.app import open_data
    from dashboards.widgets import artifact_file

    open_data([])
    path = artifact_file(name)
    if path is not None:
        st.text(f"serving {path.name}")


def test_a_corrupt_artifact_is_not_served_but_named_with_the_repair(tmp_path, monkeypatch):
    from streamlit.testing.v1 import AppTest

    from storage.artifacts import artifact_path, put_bytes

    store = data_paths(tmp_path).artifacts
    name = put_bytes(store, b"an overlay video's bytes", ".mp4")
    monkeypatch.setenv("RINGSIDE_DATA", str(tmp_path))
    app = AppTest.from_function(show_artifact, args=(name,), default_timeout=60).run()
    assert [t.value for t in app.text] == [f"serving {name}"] and not app.warning

    artifact_path(store, name).write_bytes(b"an overlay video's bytes, flipped")
    app = AppTest.from_function(show_artifact, args=(name,), default_timeout=60).run()
    assert not app.exception, app.exception
    assert not app.text, "the corrupt file was served"
    (warning,) = app.warning
    assert f"Artifact `{name}` is corrupt" in warning.value
    assert "`ringside check --repair`" in warning.value


def test_an_artifact_is_hashed_again_only_once_its_file_changes(tmp_path, monkeypatch):
    from dashboards import widgets
    from storage.artifacts import artifact_path, hashes_to_name, put_bytes

    hashed = []
    monkeypatch.setattr(
        widgets, "hashes_to_name", lambda path: hashed.append(path) or hashes_to_name(path)
    )
    path = artifact_path(tmp_path, put_bytes(tmp_path, b"stills", ".png"))

    def verdict() -> bool:
        stat = path.stat()
        return widgets.intact(path, stat.st_size, stat.st_mtime_ns)

    widgets.intact.cache_clear()
    assert [verdict() for _ in range(3)] == [True] * 3
    assert hashed == [path], "each render hashed the file again"
    path.write_bytes(b"stills, damaged")  # another size: a new verdict even on a coarse clock
    assert not verdict()
    assert hashed == [path, path]
