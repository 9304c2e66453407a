"""Dashboard page load: every page of a database holding 10 processed bouts, in headless Chromium.

The bundled sample is processed once; its per-video rows (every table with a ``video_id``
column) are then cloned under 9 more video ids, so the database holds 10 bouts that went through
every stage. Artifacts stay shared: they are named by their content, and a clone's rows name the
same ones. Re-running the pipeline on the sample assembles one dataset of all 10 bouts, a tiny
training run trains on it and is evaluated, so every page has something to draw. The result is
kept under ``data/bench/dashboard/`` and reused (``--rebuild`` builds it again).

Then ``ringside dashboard`` serves it and Debian's Chromium opens every page of
`dashboards.app.PAGES` (the Stages page once per stage): one warm-up visit, then three timed
ones. A visit lasts from ``page.goto`` until the page has written its last line
(`dashboards.widgets.READ_AT`), every chart is drawn and the layout has held still for
`STEADY_MS`; the time counted ends when that final layout first appeared.

Last line: ``dashboard_load: X s``, the slowest page's best visit. The goal (issue 9): < 2 s.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
# The tests' tiny training and evaluation settings (tests/tiny.py, free of conftest's set-up).
sys.path.insert(0, str(REPO / "tests"))

from tiny import TINY_EVALUATE_FLAGS, TINY_TRAIN_FLAGS  # noqa: E402

from dashboards.app import PAGES  # noqa: E402
from dashboards.queries import metric_stages  # noqa: E402
from dashboards.widgets import READ_AT  # noqa: E402
from flows.cli.servers import wait_until_serving  # noqa: E402
from storage.assets import SAMPLE_VIDEO, pull  # noqa: E402
from storage.db import connect  # noqa: E402
from storage.paths import data_paths  # noqa: E402

BOUTS = 10
ADVERSARY = "A"
CHROMIUM = "/usr/bin/chromium"
VISITS = 3
TRAIN_ITERATIONS = 20
# Query-parameter variants of a page, beyond its defaults, that draw different things.
VARIANTS: dict[str, list[str]] = {"stages": [f"stage={stage}" for stage in metric_stages()]}
# The layout must hold this long to count as settled (charts and videos resize as they load).
STEADY_MS = 250
# Polled in the page: the epoch milliseconds at which its final layout first appeared (the last
# line written, every chart drawn, the height unchanged since), once it has held for STEADY_MS;
# else false.
SETTLED_SINCE = """([readAt, steadyMs]) => {
  const main = document.querySelector('[data-testid="stMain"]');
  const charts = [...document.querySelectorAll('[data-testid="stVegaLiteChart"]')];
  const drawn = charts.every(chart => chart.querySelector('canvas, svg'));
  const ready = main && main.textContent.includes(readAt) && drawn;
  const state = ready ? main.scrollHeight : -1;
  const now = performance.timeOrigin + performance.now();
  if (window.__benchState !== state) {
    window.__benchState = state;
    window.__benchSince = now;
    return false;
  }
  return ready && now - window.__benchSince >= steadyMs ? window.__benchSince : false;
}"""


def cli(data: Path, *argv: str) -> str:
    """Run ``ringside --data DATA ARGV...`` in a process of its own; its output."""
    done = subprocess.run(
        [sys.executable, "-m", "flows.cli", "--data", str(data), *argv, "--json"],
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        raise SystemExit(f"ringside {' '.join(argv)} failed:\n{done.stdout}\n{done.stderr}")
    return done.stdout


def scalar(data: Path, sql: str, params: list | None = None):
    with connect(data_paths(data).db, read_only=True) as con:
        row = con.execute(sql, params or []).fetchone()
    return None if row is None else row[0]


def processed(data: Path) -> bool:
    """Whether ``data`` holds a video with a dataset output (the pipeline's last stage)."""
    return data_paths(data).db.exists() and bool(
        scalar(data, "SELECT count(*) FROM stage_outputs WHERE stage = 'dataset'")
    )


def built(data: Path) -> bool:
    """Whether ``data`` holds the finished benchmark database: the bouts and an evaluation."""
    return (
        processed(data)
        and scalar(data, "SELECT count(*) FROM videos") == BOUTS
        and bool(scalar(data, "SELECT count(*) FROM stage_outputs WHERE stage = 'evaluate'"))
    )


def clone_bouts(data: Path, bouts: int) -> None:
    """Copy the one processed video's rows under ``bouts - 1`` new video ids, in one transaction.

    Every table with a ``video_id`` column is copied, except those keyed by a dataset (a dataset
    is assembled from its members, not copied); a ``path`` column gets a file name per bout so
    the pages can tell the bouts apart, and ``registered_at`` a second more per bout, so the
    bouts come in order as if registered one after the other.
    """
    with connect(data_paths(data).db) as con:
        ((video_id, path),) = con.execute("SELECT video_id, path FROM video_files").fetchall()
        columns = con.execute(
            "SELECT table_name, list(column_name) FROM information_schema.columns "
            "WHERE table_schema = 'main' GROUP BY table_name"
        ).fetchall()
        tables = {
            table: names
            for table, names in columns
            if "video_id" in names and "dataset_key" not in names
        }
        con.begin()
        for bout in range(1, bouts):
            # A made-up SHA-256, as a video id is one.
            clone = hashlib.sha256(f"{video_id} bout {bout}".encode()).hexdigest()
            changed = {
                "video_id": ("?", clone),
                "path": ("?", str(Path(path).with_name(f"bout{bout + 1:02d}.mp4"))),
                "registered_at": ("registered_at + to_seconds(?)", bout),
            }
            for table, names in tables.items():
                replaced = [
                    (f"{sql} AS {name}", v) for name, (sql, v) in changed.items() if name in names
                ]
                con.execute(
                    f"INSERT INTO {table} SELECT * REPLACE ({', '.join(r for r, _ in replaced)}) "
                    f"FROM {table} WHERE video_id = ?",
                    [*(v for _, v in replaced), video_id],
                )
        con.commit()


def build(root: Path, sample: Path) -> Path:
    """The benchmark's data directory under ``root``, built unless it is there already."""
    data = root / "bouts"
    if built(data):
        return data
    single = root / "sample"
    if not processed(single):
        cli(single, "process", str(sample), "--adversary", ADVERSARY)
    shutil.rmtree(data, ignore_errors=True)
    data.mkdir(parents=True)
    shutil.copy2(data_paths(single).db, data_paths(data).db)
    data_paths(data).artifacts.symlink_to(data_paths(single).artifacts)
    clone_bouts(data, BOUTS)
    # The sample again: every stage cached, and one dataset assembled from all the bouts.
    cli(data, "process", str(sample), "--adversary", ADVERSARY)
    dataset = scalar(
        data,
        "SELECT dataset_key FROM dataset_members GROUP BY ALL HAVING count(*) = ?",
        [BOUTS],
    )
    if dataset is None:
        raise SystemExit(f"no dataset of {BOUTS} bouts was assembled in {data}")
    iterations = ["--train-iterations", str(TRAIN_ITERATIONS)]
    cli(data, "train", "--dataset", dataset, *TINY_TRAIN_FLAGS, *iterations)
    run = scalar(
        data, "SELECT key FROM stage_outputs WHERE stage = 'train' AND video_id = ?", [dataset]
    )
    cli(data, "evaluate", "--run", run, *TINY_EVALUATE_FLAGS)
    return data


def describe(data: Path) -> None:
    """What the database holds: videos, rows (the largest tables), file size."""
    db = data_paths(data).db
    with connect(db) as con:  # writable once: brings the schema up to date for the pages
        videos = con.execute("SELECT count(*) FROM videos").fetchone()[0]
        names = [r[0] for r in con.execute("SHOW TABLES").fetchall()]
        rows = {n: con.execute(f'SELECT count(*) FROM "{n}"').fetchone()[0] for n in names}
        done = con.execute(
            "SELECT stage, count(*) FROM stage_outputs GROUP BY stage ORDER BY stage"
        ).fetchall()
    largest = sorted(rows.items(), key=lambda item: -item[1])[:5]
    print(
        f"database {db}: {videos} videos, {sum(rows.values())} rows in {len(rows)} tables, "
        f"{db.stat().st_size / 1e6:.1f} MB"
    )
    print("  largest tables: " + ", ".join(f"{n} {c}" for n, c in largest))
    print("  outputs: " + ", ".join(f"{stage} {count}" for stage, count in done))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def visit(page, url: str) -> float:
    """Seconds from ``page.goto(url)`` until the page's final layout first appeared."""
    start = time.time()
    page.goto(url)
    settled = page.wait_for_function(
        SETTLED_SINCE, arg=[READ_AT, STEADY_MS], polling=50, timeout=120_000
    ).json_value()
    if page.locator('[data-testid="stException"]').count():
        raise SystemExit(f"{url} shows an exception:\n{page.inner_text('body')[:2000]}")
    if "held the database" in page.inner_text("body"):
        raise SystemExit(f"{url} waited for the database in vain")
    return settled / 1000 - start


def time_pages(data: Path) -> dict[str, list[float]]:
    """Each page URL (path and query) -> its timed visits' seconds."""
    from playwright.sync_api import sync_playwright

    port = free_port()
    url = f"http://127.0.0.1:{port}"
    server = subprocess.Popen(
        [sys.executable, "-m", "flows.cli", "--data", str(data), "dashboard", "--port", str(port)]
        + ["--no-browser"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    home = next(iter(PAGES))
    shown = [
        f"{'' if path == home else path}{'?' + query if query else ''}"
        for path in PAGES
        for query in ["", *VARIANTS.get(path, [])]
    ]
    spent: dict[str, list[float]] = {}
    try:
        if not wait_until_serving(url, server, timeout_s=90):
            raise SystemExit("the dashboard never answered")
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            for address in shown:
                visit(page, f"{url}/{address}")  # warm-up: the server's first render imports
                spent["/" + address] = [visit(page, f"{url}/{address}") for _ in range(VISITS)]
            browser.close()
    finally:
        # As Ctrl-C would: the command takes Streamlit down with it.
        server.send_signal(signal.SIGTERM)
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait()
    return spent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rebuild", action="store_true", help="build the database again")
    args = parser.parse_args()
    assets = data_paths().assets
    pull(assets, log=lambda _line: None)
    # Every data directory here shares the one copy of the assets and one Prefect home.
    root = data_paths().root / "bench" / "dashboard"
    os.environ["RINGSIDE_ASSETS"] = str(assets)
    os.environ.setdefault("PREFECT_HOME", str(root / "prefect"))
    if args.rebuild:
        shutil.rmtree(root / "bouts", ignore_errors=True)
    start = time.perf_counter()
    data = build(root, assets / SAMPLE_VIDEO)
    print(f"built or found in {time.perf_counter() - start:.0f} s")
    describe(data)
    spent = time_pages(data)
    width = max(map(len, spent))
    for address, seconds in spent.items():
        runs = ", ".join(f"{s:.2f}" for s in seconds)
        print(f"{address:<{width}}  best {min(seconds):.2f} s  (visits: {runs})")
    slowest = max(spent, key=lambda address: min(spent[address]))
    print(f"slowest page: {slowest}; best of {VISITS} after a warm-up visit, goal < 2 s")
    print(f"dashboard_load: {min(spent[slowest]):.2f} s")


if __name__ == "__main__":
    main()
