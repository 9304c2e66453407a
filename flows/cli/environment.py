"""What every command sets up: Prefect's settings in the environment, the server its flows
report to, and its exit codes."""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from pathlib import Path

from flows.serve import private_server
from storage.paths import DataPaths

EXIT_FAILED = 1

EXIT_BAD_INPUT = 2


def prepare_environment(paths: DataPaths, *, verbose: bool) -> None:
    """Prefect settings Ringside needs, unless the user has set them: its home (ephemeral
    server database, cached results) inside the data directory, no telemetry, a quiet console."""
    os.environ["RINGSIDE_DATA"] = str(paths.root)
    # Workers and the runs they start inherit where the results are.
    if paths.lake is not None:
        os.environ["RINGSIDE_RESULTS"] = str(paths.lake)
        os.environ["RINGSIDE_SHARED"] = str(paths.lake.shared)
    os.environ.setdefault("PREFECT_HOME", str(paths.prefect_home))
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120")
    # FFmpeg's own complaints ("moov atom not found") would bury our one-line errors.
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    # MuJoCo picks its offscreen GL backend when first imported: EGL renders without a screen
    # (Mesa's software EGL on a machine without a GPU).
    os.environ.setdefault("MUJOCO_GL", "egl")
    # Torch's OpenMP threads spin while they wait; when another process shares the cores, the
    # training updates on 2 threads ran 2-15x slower than on 1 (measured during a long run).
    # Passive waiting keeps 2 threads at least as fast as 1 on a shared machine.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    if not verbose:
        # Flow and task logs still reach the Prefect API and UI; the terminal shows our summary.
        os.environ.setdefault("PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL", "CRITICAL")
    if "PREFECT_API_URL" not in os.environ:
        from flows.launch import served_api

        # While `ringside serve` runs on this data directory, every run reports to its server
        # and shows in its UI; otherwise a flow command starts a server of its own
        # (`flow_server`).
        api = served_api(paths)
        if api is not None:
            os.environ["PREFECT_API_URL"] = api


def make_prefect_home() -> None:
    """Prefect creates its home with a plain mkdir and cannot start its server without it. Made
    once the command line has parsed, so that `--help` or a mistyped command creates nothing."""
    Path(os.environ["PREFECT_HOME"]).expanduser().mkdir(parents=True, exist_ok=True)


@contextlib.contextmanager
def flow_server(paths: DataPaths):
    """Where a command's flows report: `ringside serve`'s server or the user's
    (PREFECT_API_URL), else a private server started here, once the command has checked its
    input (it takes seconds to start: a mistyped path waited for it). Then the runs a killed
    command left RUNNING are marked crashed."""
    if "PREFECT_API_URL" not in os.environ:
        # Not Prefect's temporary server: a killed command would leave that one running.
        os.environ["PREFECT_API_URL"] = private_server(paths)
    # Imported here so that the settings below (no heartbeats) hold in a fresh process too.
    import prefect.context  # noqa: F401

    with prefect_settings_of_this_command():
        _crash_stale_flow_runs(paths.db)
        yield


@contextlib.contextmanager
def prefect_settings_of_this_command():
    """Prefect reads its settings from the environment when first imported; a later command in
    the same process (the tests, a notebook) must use its own (its data directory, its server),
    not the first command's. No flow run sends heartbeats: Prefect finds crashed runs by them,
    which Ringside marks itself (`flows.runs.crash_stale_flow_runs`), and each flow run's end
    waited for the heartbeat thread's next second (0.3 s a run: 3.5 s of a cached `process`'s
    23 s)."""
    if "prefect" not in sys.modules:
        yield
        return
    from prefect.context import SettingsContext
    from prefect.settings import Settings

    settings = Settings().copy_with_update(updates={"flows.heartbeat_frequency": None})
    with SettingsContext(profile=SettingsContext.get().profile, settings=settings):
        yield


def _crash_stale_flow_runs(db: Path) -> None:
    """Tidy Prefect before a run: a killed command's flow runs would read RUNNING for ever. A
    failure here must not stop the run, so it is only logged."""
    from flows.runs import crash_stale_flow_runs

    try:
        marked = crash_stale_flow_runs(db)
    except Exception as error:  # the API unreachable, a changed Prefect: the run goes on
        logging.getLogger("ringside").debug("stale flow runs not marked: %s", error)
        return
    if marked:
        logging.getLogger("ringside").info("marked %d stale flow runs as crashed", marked)
