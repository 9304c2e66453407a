"""Shared fixtures. Prefect's settings are fixed here, before anything imports Prefect."""

from __future__ import annotations

import contextlib
import functools
import io
import json
import os
import shutil
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

# Named as a stage's scratch folder (`storage.files.scratch_dir`: this process's pid inside), so
# that a later session removes the home of one that was killed (`orphaned_scratch`, below).
_PREFECT_HOME = tempfile.mkdtemp(prefix=f"ringside-tests-{os.getpid()}-")
os.environ["PREFECT_HOME"] = _PREFECT_HOME
os.environ["PREFECT_SERVER_ANALYTICS_ENABLED"] = "false"
os.environ["PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL"] = "CRITICAL"
os.environ["PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS"] = "120"
os.environ["OPENCV_FFMPEG_LOGLEVEL"] = "-8"
os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen rendering, as `ringside` sets it
# As `ringside` sets it (flows/cli/environment.py).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
# Every test's data directory shares the one pulled copy of the assets.
REPO = Path(__file__).resolve().parent.parent
os.environ.setdefault(
    "RINGSIDE_ASSETS", str(Path(os.environ.get("RINGSIDE_DATA", REPO / "data")) / "assets")
)

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from lakes import new_lake, start_cluster, stop_cluster  # noqa: E402
from outputs import stage_contents  # noqa: E402, F401  (tests import it from here)
from tiny import (  # noqa: E402, F401  (tests import them from here)
    TINY_EVALUATE,
    TINY_EVALUATE_FLAGS,
    TINY_PIPELINE_FLAGS,
    TINY_TRAIN,
    TINY_TRAIN_FLAGS,
    toml,
)

from storage.assets import SAMPLE_VIDEO, pull  # noqa: E402
from storage.check import orphaned_scratch  # noqa: E402
from storage.paths import data_paths  # noqa: E402

for _orphan in orphaned_scratch():  # a killed session's Prefect home, a killed stage's scratch
    shutil.rmtree(_orphan, ignore_errors=True)


def pytest_sessionfinish(session, exitstatus) -> None:
    """The suite's Prefect home goes with the session (one was left in /tmp per run)."""
    if _suite_servers:
        from flows.serve import send_logs_and_events, stop_process

        send_logs_and_events()
        for server in _suite_servers:
            stop_process(server, 10.0)
    shutil.rmtree(_PREFECT_HOME, ignore_errors=True)


# The Prefect servers `_suite_api` started (the last one serves).
_suite_servers: list[subprocess.Popen] = []


@functools.cache
def _suite_api() -> str:
    """One Prefect server on the suite's Prefect home, for the commands this process runs."""
    from flows.serve import started_server

    return started_server(data_paths(Path(_PREFECT_HOME) / "server"), _suite_servers)


@pytest.fixture(scope="session", autouse=True)
def suite_prefect_server():
    """A command run in this process on the suite's Prefect home reports to one server of the
    suite's instead of starting its own (`flows.cli.environment.flow_server`): the starts took
    about 4 s each, 140 s of three test files' 680. The same database either way; commands run
    as processes, and those given a Prefect home of their own, still start their own. For the
    whole session, so that module and session fixtures' commands use it too (in function scope
    they each started a server on a new database: 8.4 s each, 25 s of test_shot_cuts' 105)."""
    import flows.cli.environment as environment

    own = environment.private_server

    def suite_or_own(paths):
        if os.environ.get("PREFECT_HOME") != _PREFECT_HOME:
            return own(paths)
        if _suite_servers and _suite_servers[-1].poll() is not None:
            _suite_api.cache_clear()  # stopped under us: a later test starts anew
        return _suite_api()

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(environment, "private_server", suite_or_own)
        yield


@pytest.hookimpl(optionalhook=True)  # a hook of pytest-xdist's, which `-p no:xdist` leaves out
def pytest_xdist_make_scheduler(config, log):
    """`make test` runs the tests on two processes (`-n 2 --dist loadfile`): a file's tests on
    one, in order. The files on the shared `sample_run` all go to one process, in the order a
    single process runs them: they add reruns, picks and trainings to it and count what they
    find (spread over both, 11 tests failed)."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class SampleRunTogether(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            path = nodeid.split("::", 1)[0]
            return "sample_run" if _uses_sample_run(path) else path

    return SampleRunTogether(config, log)


@functools.cache
def _uses_sample_run(path: str) -> bool:
    return "sample_run" in (REPO / path).read_text()


@pytest.fixture(scope="module")
def one_torch_thread():
    """One torch thread for a module that trains: on a shared 2-core machine more threads run
    many times slower (torch imported here, not at the top: most tests never load it)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def assets() -> Path:
    """The pulled assets (weights, sample videos), fetched once if missing."""
    root = data_paths().assets
    pull(root, dev=True, log=lambda _line: None)
    return root


@pytest.fixture(scope="session")
def punch(assets: Path):
    """DeepMimic's punch performed by both fighters, 1.2 m apart and facing each other (a
    `ReferenceMotions`)."""
    import mujoco

    from models.humanoid.boxer import boxer_mjcf
    from models.humanoid.compiled import velocities
    from models.maaip.demonstrations import facing_reference
    from tasks.deepmimic import clip_path, load_deepmimic, retarget

    qpos = retarget(load_deepmimic(clip_path(assets, "punch")))
    model = mujoco.MjModel.from_xml_string(boxer_mjcf())
    return facing_reference(qpos, velocities(model, qpos, 30.0), distance=1.2)


@pytest.fixture(scope="session")
def sample_video(assets: Path) -> Path:
    return assets / SAMPLE_VIDEO


def process_argv(data: Path, video: Path, *more: str, until: str = "dataset") -> list[str]:
    """`ringside process VIDEO --adversary A` on ``data`` up to ``until`` (by default the
    per-video stages: training and evaluation have tests of their own), then ``more``."""
    return ["--data", str(data), "process", str(video), "--adversary", "A", "--until", until, *more]


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    """Run the ``ringside`` command in this process: (exit code, stdout, stderr)."""
    from flows.cli import main

    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def query(data: Path, sql: str, params: list | None = None) -> list[tuple]:
    """Rows of ``sql`` on the database of data directory ``data``, opened read-only."""
    from storage.db import connect

    with connect(data / "ringside.duckdb", read_only=True) as con:
        return con.execute(sql, params or []).fetchall()


def count(db: Path, sql: str) -> int:
    return query(db.parent, sql)[0][0]


@pytest.fixture(scope="session")
def sample_processing(tmp_path_factory, sample_video: Path) -> tuple[Path, str | None]:
    """The sample through every per-video stage in chunks of 30 frames (so chunk borders are
    crossed): its data directory, and what the command said if it failed (None if not)."""
    from flows.cli import main

    data = tmp_path_factory.mktemp("sample_run") / "data"
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(process_argv(data, sample_video, "--ingest-chunk-frames", "30"))
    return data, None if code == 0 else f"exit {code}: {err.getvalue().strip()[-2000:]}"


@pytest.fixture(scope="session")
def sample_run(sample_processing: tuple[Path, str | None]) -> Path:
    """A data directory where the sample went through every stage, in chunks of 30 frames.
    Tests may add picks or reruns to it, never remove anything. Each test process (`make test`
    runs two) builds its own. When the sample does not go through, the tests on it skip,
    naming why, and one test fails with the same words (tests/test_sample.py)."""
    data, problem = sample_processing
    if problem is not None:
        pytest.skip(f"the sample did not go through the stages: {problem}")
    return data


def sample_training(data: Path) -> tuple[str, str | None]:
    """The key of the sample's first dataset (the fixture's own, before any test's rerun) and
    why training cannot start from it, in words, or None when it can: what training itself
    says, and what the lift and the dataset dropped on the way."""
    from storage.db import connect
    from tasks.dataset.store import training_data
    from tasks.errors import BadInput

    (key,) = query(data, "SELECT dataset_key FROM datasets ORDER BY created_at LIMIT 1")[0]
    with connect(data / "ringside.duckdb", read_only=True) as con:
        try:
            training_data(con, key)
            return key, None
        except BadInput as error:
            refused = str(error)
    counts = dict(
        query(
            data,
            "SELECT m.stage || '.' || m.name, m.value FROM stage_metrics m JOIN "
            "(SELECT stage, key FROM stage_outputs WHERE stage IN ('lift', 'dataset') "
            "QUALIFY row_number() OVER (PARTITION BY stage ORDER BY created_at) = 1) USING "
            "(stage, key) WHERE m.name LIKE 'frames_rejected_%' OR m.name IN "
            "('steps_rejected', 'steps_bridged', 'clips_interaction')",
        )
    )
    said = ", ".join(f"{name} {value:g}" for name, value in sorted(counts.items()) if value)
    return key, f"{refused}; on the way: {said or 'nothing dropped'}"


@pytest.fixture(scope="session")
def sample_dataset(sample_run: Path) -> str:
    """The key of the sample's first dataset, which training starts from. When it cannot, the
    tests that train on it skip, naming why, and one test fails with the same words
    (tests/test_sample.py): not one failure for each of them."""
    key, problem = sample_training(sample_run)
    if problem is not None:
        pytest.skip(f"the sample cannot be trained on: {problem}")
    return key


def copy_data(source: Path, data: Path) -> Path:
    """A data directory of a test's own holding ``source``'s results (database and artifacts;
    assets stay shared through ``RINGSIDE_ASSETS``), for tests whose runs must not change a
    shared fixture's. Returns ``data``."""
    data.mkdir(parents=True)
    for name in ("ringside.duckdb", "ringside.duckdb.wal"):  # a WAL only if not checkpointed
        if (source / name).exists():
            shutil.copy2(source / name, data / name)
    shutil.copytree(source / "artifacts", data / "artifacts")
    return data


def render_page(path: str) -> None:
    """One dashboard page as a script of its own, for Streamlit's AppTest (which runs a
    function's body, so the import is inside), on the data directory of ``$RINGSIDE_DATA``."""
    from dashboards.app import PAGES, open_data

    open_data([])
    PAGES[path][1]()


def read_video(path: Path) -> tuple[str, list[np.ndarray]]:
    """A video file's codec (FourCC, e.g. 'avc1') and every frame OpenCV decodes from it."""
    capture = cv2.VideoCapture(str(path))
    fourcc = int(capture.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode()
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(frame)
    capture.release()
    return fourcc, frames


def write_video(path: Path, frames: list[np.ndarray], fps: float = 30.0) -> Path:
    """Write BGR frames as an MPEG-4 Part 2 file (the codec OpenCV's wheel can write)."""
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    assert writer.isOpened(), f"OpenCV cannot write {path}"
    for frame in frames:
        writer.write(frame)
    writer.release()
    return path


def dropped_frames_copy(source: Path, path: Path, keep_from: int, every: int) -> Path:
    """A variable-frame-rate copy of ``source`` as a camera dropping frames makes it: every
    frame before ``keep_from``, then one in ``every``, each at its original time (H.264 by the
    ffmpeg imageio-ffmpeg ships; timestamps passed through, not re-timed)."""
    import imageio_ffmpeg

    keep = f"lt(n\\,{keep_from})+not(mod(n-{keep_from}\\,{every}))"
    command = [imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-y", "-i", str(source)]
    command += ["-vf", f"select='{keep}'", "-fps_mode", "passthrough"]
    command += ["-c:v", "libx264", "-crf", "12", "-preset", "veryfast", str(path)]
    subprocess.run(command, check=True)
    return path


def moving_box_frames(n: int, background: tuple[int, int, int], start: int = 0) -> list:
    """A grey box sliding to and fro across a plain background: motion, but no cut (a box that
    jumped back to its start would be a change of picture, which the cut detector finds)."""
    frames = []
    for i in range(start, start + n):
        frame = np.full((96, 128, 3), background, np.uint8)
        x = 8 + abs((i * 3) % 180 - 90)
        cv2.rectangle(frame, (x, 30), (x + 24, 70), (128, 128, 128), -1)
        frames.append(frame)
    return frames


@pytest.fixture
def two_shot_video(tmp_path: Path) -> Path:
    """30 frames of a blue scene, then 30 of a red one: one cut, at frame 30."""
    frames = moving_box_frames(30, (200, 60, 20)) + moving_box_frames(30, (20, 40, 210), 30)
    return write_video(tmp_path / "two_shots.mp4", frames)


def child_pids(pid: int) -> list[int]:
    """Processes whose parent is ``pid`` (Linux /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie does not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


# Prefect's API, as its UI reads it, and waiting on it (the served-server tests).
WAIT_S = 150.0


def api_post(api: str, path: str, body: dict) -> list[dict]:
    request = urllib.request.Request(
        f"{api}/{path}",
        data=json.dumps(body).encode(),
        method="POST",
        headers={"Content-Type": "application/json"},
    )
    with urllib.request.urlopen(request, timeout=10) as answer:
        return json.loads(answer.read())


def flow_runs(api: str, flow: str) -> list[dict]:
    """Every flow run of ``flow`` that Prefect's API (and so its UI) lists."""
    return api_post(api, "flow_runs/filter", {"flows": {"name": {"any_": [flow]}}})


def wait_for(what: str, check, timeout_s: float = WAIT_S, log: Path | None = None):
    """``check()``'s first truthy value, polled until ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        found = check()
        if found:
            return found
        time.sleep(1.0)
    tail = log.read_text(errors="replace")[-3000:] if log and log.exists() else ""
    raise AssertionError(f"timed out after {timeout_s:.0f} s waiting for {what}\n{tail}")


@pytest.fixture(scope="session")
def postgres_port(tmp_path_factory) -> int:
    """A PostgreSQL cluster for the lake backend's tests, stopped at the end of the session."""
    folder = Path(tempfile.mkdtemp(prefix="ringside-lakes-"))
    try:
        yield start_cluster(folder)
    finally:
        stop_cluster(folder)
        shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture
def lake(postgres_port: int, tmp_path: Path):
    """A fresh lake: its own catalog database, ``tmp_path/shared`` its shared folder."""
    return new_lake(postgres_port, tmp_path / "shared")
