"""Ringside's Prefect server and its deployments: ``ringside serve``, ``ringside schedule`` and the
dashboard's reruns.

``ringside serve`` starts ``prefect server start`` on the data directory's Prefect home (unless
``PREFECT_API_URL`` names a server already) and serves two deployments from one runner: the
pipeline, ``video_to_opponent/ringside``, run on demand, and, with ``--watch``,
``watch_folder/ringside`` on a schedule. It leaves ``DATA/prefect/served.json`` behind while it
runs, so the other ``ringside`` commands and the dashboard find the server.

Prefect reads its settings when first imported, so nothing here imports Prefect at module level:
``served_api`` runs before the CLI decides where Prefect should report.
"""

from __future__ import annotations

import atexit
import contextlib
import fcntl
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.parse
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

from flows.launch import (
    DEPLOYMENT,
    answers,
)
from storage.paths import DataPaths

DEFAULT_CRON = "*/5 * * * *"
SERVER_LOG = "server.log"
# The machine has few cores: one flow run at a time, pipeline or watcher, the others wait.
RUN_LIMIT = 1
# `ringside worker` and `ringside serve --workers N` take the pipeline's runs from this Prefect
# process work pool, each one run at a time.
WORK_POOL = "ringside"
WORKER_LOG = "worker.log"
# Prefect's defaults suit hourly schedules: its scheduler looks at changed deployments every 5 s
# and tops up schedules every 60 s, a served runner asks for due runs every 10 s. Shorter loops
# let a schedule of seconds fire on time and a `ringside schedule` run start within seconds; each
# loop is one small query on a local server. Users' own values win.
SERVER_SETTINGS = {
    "PREFECT_SERVER_SERVICES_SCHEDULER_LOOP_SECONDS": "10",
    "PREFECT_SERVER_SERVICES_SCHEDULER_RECENT_DEPLOYMENTS_LOOP_SECONDS": "2",
}
RUNNER_SETTINGS = {"PREFECT_RUNNER_POLL_FREQUENCY": "2"}
# How long `ringside serve` waits for its server (the first start migrates its database).
SERVER_START_S = 180.0
# Workers likewise: Prefect's ask every 10 s, so two runs scheduled together often ran one after
# the other on two idle workers.
WORKER_SETTINGS = {"PREFECT_WORKER_QUERY_SECONDS": "2"}
# server.log keeps the server's warnings and errors (a failing scheduler says so there), not a
# line per request: the runner alone asks every 2 s.
SERVER_LOG_SETTINGS = {
    "PREFECT_SERVER_LOGGING_LEVEL": "WARNING",
    "PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL": "WARNING",
}


def server_command(port: int) -> list[str]:
    """``prefect server start`` on localhost, with its UI, in the foreground."""
    return [
        sys.executable,
        "-m",
        "prefect",
        "server",
        "start",
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
    ]


def port_free(port: int) -> bool:
    """Whether nothing listens on ``127.0.0.1:port``."""
    with socket.socket() as s:
        # As servers bind (uvicorn, PostgreSQL): a closed connection in TIME_WAIT does not count.
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def die_with_parent() -> None:
    """In the child before exec (Linux): SIGTERM it when its parent dies, even killed with
    SIGKILL, so no orphaned server keeps the port (nor a benchmark's helper the cores)."""
    import ctypes

    pr_set_pdeathsig = 1
    ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, signal.SIGTERM)


def start_server(paths: DataPaths, port: int) -> subprocess.Popen:
    """Start Ringside's Prefect server; its output goes to ``DATA/prefect/server.log``.

    It gets a session of its own so that Ctrl-C reaches only ``ringside serve``, which stops the
    runner first (it pauses the schedules through the server) and then the server.
    """
    log_path = paths.prefect_home / SERVER_LOG
    log_path.parent.mkdir(parents=True, exist_ok=True)
    env = {**SERVER_SETTINGS, **os.environ, **SERVER_LOG_SETTINGS}
    env.pop("PREFECT_API_URL", None)  # the server does not report to anyone
    with log_path.open("ab") as log:
        return subprocess.Popen(
            server_command(port),
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            preexec_fn=die_with_parent if sys.platform == "linux" else None,
        )


def free_port() -> int:
    """A port nothing listens on now (the system's pick)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# The private servers this process started and has not stopped yet (`private_server`).
_private: list[subprocess.Popen] = []


def private_server(paths: DataPaths) -> str:
    """Start a Prefect server for this command alone and return its API URL.

    Prefect would start a temporary server of its own, which outlives a command killed with
    SIGKILL (about 257 MB each, measured). This one is started with `die_with_parent` from the
    main thread, so the kernel stops it with the command however the command ends, an exit
    handler stops it when the command exits, and `stop_private_servers` when a command run
    in-process returns. Its log joins ``ringside serve``'s.
    """
    return started_server(paths, _private)


def started_server(paths: DataPaths, started: list[subprocess.Popen]) -> str:
    """Start a Prefect server on ``paths``' Prefect home and return its API URL once it is up.
    Each process started is added to ``started`` at once, for the caller to stop however it
    ends, and is stopped at the interpreter's exit. ServerError saying why in a line when it
    does not come up."""
    timeout_s = float(os.environ.get("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", 120))
    # Servers on one data directory share Prefect's database, which a server migrates as it
    # starts: two commands started at once on a new data directory both migrated it, and one
    # failed ("duplicate column name"). Starting one at a time on a lock avoids it.
    home = paths.prefect_home
    home.mkdir(parents=True, exist_ok=True)
    with (home / "server-start.lock").open("a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        # The port is free when picked, but another process may bind it before the server
        # does (seconds later): then the server stops at once and starts again on another.
        for _ in range(PORT_TRIES):
            port = free_port()
            api_url = f"http://127.0.0.1:{port}/api"
            written = server_log_size(paths)
            server = start_server(paths, port)
            # Stopped on the way out from here on: a SIGTERM while it migrates its database
            # once left it running after the command had gone.
            atexit.register(stop_process, server, 5.0)
            started.append(server)
            up = wait_until_up(api_url, server, timeout_s)
            if up or not port_taken(paths, written):
                break
    if not up:
        exited = server.poll() is not None
        stop_process(server, 5.0)
        raise ServerError(startup_failure(paths, written, exited, timeout_s))
    return api_url


PORT_TRIES = 3


def port_taken(paths: DataPaths, written: int) -> bool:
    """Whether the server started when its log held ``written`` bytes stopped because its
    port was in use (Prefect's own words)."""
    return any("is already in use" in line for line in logged_since(paths, written))


def logged_since(paths: DataPaths, written: int) -> list[str]:
    """The server log's lines after its first ``written`` bytes."""
    with (paths.prefect_home / SERVER_LOG).open("rb") as lines:
        lines.seek(written)
        return lines.read().decode(errors="replace").splitlines()


class ServerError(RuntimeError):
    """Prefect's server could not be started for a command; the message says why in a line."""


def server_log_size(paths: DataPaths) -> int:
    """Bytes in the server log now: a start's own lines follow (`startup_failure`)."""
    log = paths.prefect_home / SERVER_LOG
    return log.stat().st_size if log.exists() else 0


def startup_failure(paths: DataPaths, written: int, exited: bool, timeout_s: float) -> str:
    """Why a server started when its log held ``written`` bytes did not come up, in a line:
    its database damaged (from what it logged), it stopped, or it took too long."""
    log = paths.prefect_home / SERVER_LOG
    said = logged_since(paths, written)
    damaged = next(
        (
            line.split("DatabaseError)", 1)[-1].strip()
            for line in reversed(said)
            if "sqlite3.DatabaseError" in line
        ),
        None,
    )
    if damaged is not None:
        return (
            f"Prefect's database {prefect_database()} is damaged ({damaged}): "
            "`ringside check --repair` sets it aside (it holds Prefect's run history "
            "only; Ringside's results are in the data directory's ringside.duckdb)"
        )
    when = "stopped as it started" if exited else f"did not start within {timeout_s:g} s"
    return f"Prefect's server {when}; its log: {log}"


def prefect_database() -> Path | None:
    """Prefect's own SQLite database (its flow runs), as PREFECT_HOME places it; None where
    PREFECT_API_DATABASE_CONNECTION_URL puts it elsewhere (PostgreSQL)."""
    url = os.environ.get("PREFECT_API_DATABASE_CONNECTION_URL")
    if url and not url.startswith("sqlite"):
        return None
    if url:
        return Path(url.split(":///", 1)[1]).expanduser()
    return Path(os.environ.get("PREFECT_HOME", "~/.prefect")).expanduser() / "prefect.db"


def stop_private_servers() -> None:
    """Stop the servers `private_server` started. A command run in-process (the tests, a
    notebook) ends here, not at the interpreter's exit: the test suite had kept one idle server
    per command alive until it ended, dozens at once (about 220 MB and a few % of a core each)."""
    if _private:
        send_logs_and_events()
    while _private:
        stop_process(_private.pop(), 5.0)


def send_logs_and_events() -> None:
    """This process's Prefect logs and events sent now, before their server stops (at the
    interpreter's exit Prefect would send them to a stopped server, and say so)."""
    if "prefect" in sys.modules:
        from prefect.events.worker import EventsWorker
        from prefect.logging.handlers import APILogWorker

        for worker in (APILogWorker, EventsWorker):
            worker.drain_all(timeout=5.0, at_exit=False)


def stop_workers(workers: list[subprocess.Popen], timeout_s: float = 10.0) -> None:
    """Stop Prefect workers and the flow runs they started, each within ``timeout_s``.

    Each worker starts its runs in sessions of their own, where no signal to the worker reaches
    them, so the runs get SIGTERM first, and their worker, still up, marks each one that ended
    unfinished as Crashed (a rerun resumes it). Then each worker gets two signals: Prefect's
    worker takes a first one as "finish first" (an idle one was still running minutes later)
    and a second as "stop now". What is left after ``timeout_s`` is killed.
    """
    import psutil

    runs = []
    for worker in workers:
        with contextlib.suppress(psutil.NoSuchProcess):
            runs += psutil.Process(worker.pid).children(recursive=True)
    run_ids = set()
    for run in runs:
        with contextlib.suppress(psutil.Error):
            run_ids.add(run.environ().get("PREFECT__FLOW_RUN_ID"))
    run_ids.discard(None)
    if runs:
        _end(runs, timeout_s)
        _wait_until_ended(run_ids, timeout_s)
    for worker in workers:
        if worker.poll() is None:
            worker.send_signal(signal.SIGTERM)
    time.sleep(0.2)
    left = []
    for worker in workers:
        with contextlib.suppress(psutil.NoSuchProcess):
            left.append(psutil.Process(worker.pid))
    _end(left, timeout_s)
    for worker in workers:
        worker.wait()
        forget_worker(worker)


def _end(processes: list, timeout_s: float) -> None:
    """SIGTERM to each of ``processes`` (psutil's), SIGKILL to those left after ``timeout_s``."""
    import psutil

    for process in processes:
        with contextlib.suppress(psutil.NoSuchProcess):
            process.terminate()
    _, left = psutil.wait_procs(processes, timeout=timeout_s)
    for process in left:
        with contextlib.suppress(psutil.NoSuchProcess):
            process.kill()


# How often `serve` looks at the workers it started.
SUPERVISE_S = 1.0


@dataclass
class Supervised:
    """A worker `serve` started, and the flow-run processes below it when last looked at (with
    each one's flow run id): once the worker is dead they can no longer be found from it."""

    process: subprocess.Popen
    runs: dict[Any, str | None]


def supervise(paths: DataPaths, workers: list[Supervised]) -> list[str]:
    """Look at each worker once. A live one: note the flow runs below it. A dead one (killed,
    crashed): stop the runs it left (they would go on outside anyone's control), mark them
    Crashed in Prefect, so that the next run recomputes their outputs, and start a new worker
    in its place. One line per worker replaced."""
    import psutil

    from flows.runs import crash_flow_runs

    replaced = []
    for worker in workers:
        if worker.process.poll() is None:
            with contextlib.suppress(psutil.Error):
                below = psutil.Process(worker.process.pid).children(recursive=True)
                worker.runs = {p: worker.runs.get(p) or _flow_run_id(p) for p in below}
            continue
        dead, code = worker.process.pid, worker.process.returncode
        left = [p for p in worker.runs if p.is_running()]
        run_ids = sorted({worker.runs[p] for p in left} - {None})
        # The new worker first: the old one's runs may take seconds to stop. A run stopped by
        # SIGTERM marks itself Crashed; one that could not is marked here.
        ended = worker.process
        worker.process, worker.runs = start_worker(paths), {}
        _end(left, 10.0)
        forget_worker(ended)
        crash_flow_runs(run_ids, f"its worker (pid {dead}) died")
        how = f"signal {-code}" if code < 0 else f"exit {code}"
        replaced.append(
            f"worker {dead} died ({how}): its {len(run_ids)} flow run(s) stopped and marked "
            f"Crashed; started worker {worker.process.pid}"
        )
    return replaced


def _flow_run_id(process) -> str | None:
    """The flow run a worker's child process runs (Prefect names it in its environment)."""
    import psutil

    try:
        return process.environ().get("PREFECT__FLOW_RUN_ID")
    except psutil.Error:
        return None


def _wait_until_ended(run_ids: set[str], timeout_s: float) -> None:
    """Wait until the flow runs ``run_ids`` are no longer RUNNING in Prefect (their worker
    reports each ended run), for at most ``timeout_s``."""
    import uuid

    import httpx
    from prefect.client.orchestration import get_client
    from prefect.client.schemas.filters import (
        FlowRunFilter,
        FlowRunFilterId,
        FlowRunFilterState,
        FlowRunFilterStateType,
    )
    from prefect.client.schemas.objects import StateType

    if not run_ids:
        return
    running = FlowRunFilter(
        id=FlowRunFilterId(any_=[uuid.UUID(run) for run in run_ids]),
        state=FlowRunFilterState(type=FlowRunFilterStateType(any_=[StateType.RUNNING])),
    )
    deadline = time.monotonic() + timeout_s
    # A server already gone cannot be told anything more: nothing to wait for then.
    with contextlib.suppress(httpx.HTTPError), get_client(sync_client=True) as client:
        while client.read_flow_runs(flow_run_filter=running) and time.monotonic() < deadline:
            time.sleep(0.2)


def wait_until_up(
    api_url: str, server: subprocess.Popen, timeout_s: float = SERVER_START_S
) -> bool:
    """Whether the server answers before ``timeout_s`` (its first start migrates its database),
    from a socket it listens on itself: between `free_port` and the server's bind, another
    process may take the port, and its answer is not this server's."""
    port = urllib.parse.urlsplit(api_url).port
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and server.poll() is None:
        if answers(api_url) and listens(server, port):
            return True
        time.sleep(0.1)  # every command waits for its server: a coarser poll added 0.25 s
    return False


def listens(process: subprocess.Popen, port: int) -> bool:
    """Whether ``process`` (or a process it started) listens on TCP ``port``."""
    import psutil

    try:
        parent = psutil.Process(process.pid)
        family = [parent, *parent.children(recursive=True)]
        return any(
            c.status == psutil.CONN_LISTEN and c.laddr.port == port
            for p in family
            for c in p.net_connections(kind="tcp")
        )
    except psutil.Error:
        return False


def stop_process(process: subprocess.Popen, timeout_s: float = 30.0) -> None:
    """SIGTERM (a server or worker shuts down gracefully), then SIGKILL if it will not go."""
    if process.poll() is not None:
        return
    process.send_signal(signal.SIGTERM)
    try:
        process.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def log_tail(paths: DataPaths, lines: int = 20) -> str:
    path = paths.prefect_home / SERVER_LOG
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return ""


def parse_when(text: str, *, now: datetime) -> datetime:
    """When ``--at TEXT`` means, as an aware local time: ``now``; ``HH:MM`` (today, or tomorrow
    once that time has passed); or ISO 8601 (without an offset: local time), not in the past.
    ``now`` is aware."""
    text = text.strip()
    if text.lower() == "now":
        return now
    clock = re.fullmatch(r"(\d{1,2}):(\d{2})", text)
    if clock:
        hour, minute = int(clock[1]), int(clock[2])
        if hour > 23 or minute > 59:
            raise ValueError(f"--at {text}: no such time of day")
        when = now.replace(hour=hour, minute=minute, second=0, microsecond=0)
        return when if when > now else when + timedelta(days=1)
    try:
        when = datetime.fromisoformat(text)
    except ValueError:
        raise ValueError(
            f"--at {text}: expected 'now', HH:MM or an ISO 8601 time like 2030-06-01T18:30"
        ) from None
    when = when.astimezone() if when.tzinfo is None else when  # naive: local time
    if when < now:
        raise ValueError(f"--at {text}: that is in the past (now is {now:%Y-%m-%d %H:%M:%S})")
    return when


@dataclass(frozen=True)
class Watch:
    """The folder ``ringside serve --watch`` looks in, and when."""

    folder: Path
    adversary: str
    adversary_colour: str | None = None
    cron: str | None = DEFAULT_CRON  # used when every_s is None
    every_s: float | None = None
    until: str | None = None  # the last stage to run on the videos found there


def local_timezone() -> str:
    """This machine's IANA time zone (``$TZ``, else where ``/etc/localtime`` points), so a cron
    expression means local time as ``--at HH:MM`` does; UTC when it cannot be told."""
    from zoneinfo import available_timezones

    known = available_timezones()
    name = os.environ.get("TZ", "").lstrip(":")
    if name in known:
        return name
    target = str(Path("/etc/localtime").resolve())
    _, found, key = target.partition("zoneinfo/")
    return key if found and key in known else "UTC"


def deployments(paths: DataPaths, config: dict, watch: Watch | None) -> list:
    """Prefect deployments of the pipeline (on demand) and, with ``watch``, of the watcher (on
    its schedule), with ``paths``' root and ``config`` as default parameters. Builds and checks
    them (a bad cron expression fails here) without talking to the server."""
    from prefect.client.schemas.schedules import CronSchedule, IntervalSchedule
    from prefect.types.entrypoint import EntrypointType

    from flows.pipeline import video_to_opponent
    from flows.watch import watch_folder

    root = str(paths.root)  # flow parameters are JSON: the root goes as a string
    # By module path, so a run finds the flow wherever the runner's working directory is.
    by_module = EntrypointType.MODULE_PATH
    found = [
        video_to_opponent.to_deployment(
            DEPLOYMENT,
            parameters={"data_root": root, "config": config},
            description=f"The pipeline on {root}: `ringside schedule`, the dashboard, this UI.",
            entrypoint_type=by_module,
        )
    ]
    if watch is not None:
        if watch.every_s is not None:
            when = {"schedule": IntervalSchedule(interval=timedelta(seconds=watch.every_s))}
        else:
            try:
                when = {"schedule": CronSchedule(cron=watch.cron, timezone=local_timezone())}
            except ValueError:  # pydantic's many-line message, said in one
                raise ValueError(
                    f"--cron {watch.cron!r} is not a cron expression (minute hour day month "
                    "weekday, e.g. '*/5 * * * *')"
                ) from None
        found.append(
            watch_folder.to_deployment(
                DEPLOYMENT,
                parameters={
                    "data_root": root,
                    "folder": str(watch.folder.resolve()),
                    "adversary": watch.adversary,
                    "adversary_colour": watch.adversary_colour,
                    "config": config,
                    "until": watch.until,
                },
                description=f"New videos in {watch.folder.resolve()} through the pipeline.",
                entrypoint_type=by_module,
                **when,
            )
        )
    return found


def serve_deployments(found: list, paths: DataPaths, workers: int = 0) -> None:
    """Serve ``found`` until Ctrl-C or SIGTERM: from one runner, ``RUN_LIMIT`` runs at a time,
    or, with ``workers``, the pipeline (``found[0]``) on the work pool, where that many process
    workers started here (and any `ringside worker` elsewhere) take its runs, one each at a time.
    The runner pauses the schedules as it stops; the workers stop with it."""
    import asyncio

    from prefect.runner import Runner

    started: list[Supervised] = []
    if workers:
        ensure_work_pool()
        pipeline, *found = found
        pipeline.apply(work_pool_name=WORK_POOL)
    runner = Runner(name=DEPLOYMENT, limit=RUN_LIMIT, pause_on_shutdown=True)
    for deployment in found:
        runner.add_deployment(deployment)

    def look() -> None:
        for line in supervise(paths, started):
            print(line, file=sys.stderr, flush=True)

    try:
        started.extend(Supervised(start_worker(paths), {}) for _ in range(workers))
        asyncio.run(_run_until_stopped(runner, look if workers else None))
    finally:
        stop_workers([worker.process for worker in started])


def ensure_work_pool() -> None:
    """Create the process work pool `WORK_POOL` on the current Prefect server if it is missing."""
    from prefect.client.orchestration import get_client
    from prefect.client.schemas.actions import WorkPoolCreate
    from prefect.exceptions import ObjectAlreadyExists

    with get_client(sync_client=True) as client, contextlib.suppress(ObjectAlreadyExists):
        client.create_work_pool(WorkPoolCreate(name=WORK_POOL, type="process"))


def worker_log(paths: DataPaths) -> Path:
    """Where the process workers started on this data directory write their log."""
    return paths.prefect_home / WORKER_LOG


# Each worker's temporary directory (`start_worker`), by the worker's pid.
_worker_tmp: dict[int, Path] = {}


def worker_tmp_root(paths: DataPaths) -> Path:
    """Where the workers' temporary directories go: ``DATA/prefect/tmp``."""
    return paths.prefect_home / "tmp"


def start_worker(paths: DataPaths, limit: int = 1) -> subprocess.Popen:
    """A Prefect process worker on `WORK_POOL` of the server ``PREFECT_API_URL`` names, taking
    ``limit`` runs at a time, each in a process of its own; its log goes to
    ``DATA/prefect/worker.log``. It dies with this process, as the private servers do.

    Prefect's worker leaves a directory in the system's temporary folder for each run it starts,
    removed only when the worker exits cleanly: every `make test` left one in /tmp. So each
    worker (and its runs) gets a temporary directory of its own under `worker_tmp_root`,
    removed once the worker has ended (`forget_worker`); those of commands that were killed are
    removed by the next worker's start."""
    log_path = worker_log(paths)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    root = worker_tmp_root(paths)
    root.mkdir(parents=True, exist_ok=True)
    _sweep_tmp(root)
    tmp = Path(tempfile.mkdtemp(prefix=f"{os.getpid()}-", dir=root))
    command = [sys.executable, "-m", "prefect", "worker", "start", "--pool", WORK_POOL]
    command += ["--type", "process", "--limit", str(limit)]
    with log_path.open("ab") as log:
        worker = subprocess.Popen(
            command,
            env={**WORKER_SETTINGS, **os.environ, **SERVER_LOG_SETTINGS, "TMPDIR": str(tmp)},
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            preexec_fn=die_with_parent if sys.platform == "linux" else None,
        )
    _worker_tmp[worker.pid] = tmp
    return worker


def forget_worker(worker: subprocess.Popen) -> None:
    """Remove the temporary directory of ``worker``, which has ended."""
    tmp = _worker_tmp.pop(worker.pid, None)
    if tmp is not None:
        shutil.rmtree(tmp, ignore_errors=True)


def _sweep_tmp(root: Path) -> None:
    """Remove the worker directories under ``root`` whose command (the pid that starts each
    one's name) no longer runs: it was killed before it could remove them."""
    import psutil

    for found in root.iterdir():
        owner = found.name.partition("-")[0]
        if not (owner.isdigit() and psutil.pid_exists(int(owner))):
            shutil.rmtree(found, ignore_errors=True)


async def _run_until_stopped(runner, look=None) -> None:
    """Run ``runner`` until SIGTERM or Ctrl-C, calling ``look()`` (in a thread: it may wait on
    processes and the API) every `SUPERVISE_S` meanwhile."""
    import asyncio

    started = asyncio.create_task(runner.start())
    await asyncio.sleep(0)  # start() has set its own SIGTERM handler by now
    # That handler exits from inside the signal handler (and warns of a coroutine never
    # awaited); cancelling the runner as Ctrl-C does lets it clean up instead.
    asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, started.cancel)

    async def supervising() -> None:
        while True:
            await asyncio.to_thread(look)
            await asyncio.sleep(SUPERVISE_S)

    watcher = asyncio.create_task(supervising()) if look is not None else None
    try:
        with contextlib.suppress(asyncio.CancelledError):
            await started
    finally:
        if watcher is not None:
            watcher.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await watcher
