"""Long-running commands: the dashboard, Prefect's server and workers, schedules, the live
sparring server."""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from flows.cli.environment import EXIT_FAILED
from flows.cli.parser import overrides
from storage.paths import DataPaths

# How long the dashboard's Streamlit gets to stop on a signal (about 1 s when idle) before it is
# killed: it only reads, so a kill loses nothing, and whoever stops the dashboard (a service
# manager, a test) should not wait on Streamlit closing its sessions.
DASHBOARD_STOP_S = 1.5


def streamlit_argv(paths: DataPaths, *, host: str, port: int) -> list[str]:
    """The command line that serves the dashboard of ``paths`` with Streamlit: headless (it
    opens no browser and asks no questions), without Streamlit's usage statistics."""
    # Its file, not the module: importing the app would load Streamlit into this command.
    app = importlib.util.find_spec("dashboards.app").origin
    return [
        sys.executable,
        "-m",
        "streamlit",
        "run",
        app,
        "--server.headless",
        "true",
        "--server.address",
        host,
        "--server.port",
        str(port),
        "--browser.gatherUsageStats",
        "false",
        # No "Deploy" button: this dashboard is served from the analysts' own machines.
        "--client.toolbarMode",
        "minimal",
        "--",
        "--data",
        str(paths.root),
    ]


def wait_until_serving(url: str, server: subprocess.Popen, timeout_s: float = 60.0) -> bool:
    """Whether the dashboard at ``url`` answers its health check before ``timeout_s``."""
    import urllib.error
    import urllib.request

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and server.poll() is None:
        try:
            with urllib.request.urlopen(f"{url}/_stcore/health", timeout=2) as answer:
                return answer.status == 200
        except (urllib.error.URLError, OSError):
            time.sleep(0.2)
    return False


@contextlib.contextmanager
def sigterm_as_ctrl_c():
    """SIGTERM (a service manager, a test) raises KeyboardInterrupt while inside, so the
    long-running commands stop on it as on Ctrl-C, stopping what they started."""

    def stop(_signum, _frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def dashboard_command(args, paths: DataPaths) -> int:
    import webbrowser

    from flows.serve import die_with_parent, stop_process

    if not 0 < args.port < 65536:
        raise ValueError(f"--port must be between 1 and 65535, got {args.port}")
    shown_host = "localhost" if args.host in ("127.0.0.1", "0.0.0.0") else args.host
    url = f"http://{shown_host}:{args.port}"
    # Without a display, webbrowser would start a text browser in this very terminal.
    graphical = sys.platform in ("darwin", "win32") or any(
        os.environ.get(name) for name in ("DISPLAY", "WAYLAND_DISPLAY")
    )

    # A SIGTERM stops the server as Ctrl-C does, not orphaning it.
    with sigterm_as_ctrl_c():
        server = subprocess.Popen(
            streamlit_argv(paths, host=args.host, port=args.port),
            # Even if this command is killed, Streamlit goes with it and frees the port.
            preexec_fn=die_with_parent if sys.platform == "linux" else None,
        )
        try:
            print(f"dashboard of {paths.root} at {url} (Ctrl-C stops it)", flush=True)
            if not args.no_browser and graphical and wait_until_serving(url, server):
                webbrowser.open(url)
            return server.wait()
        except KeyboardInterrupt:
            # A SIGTERM reached only us (Ctrl-C reached Streamlit too, which stops the same on
            # SIGTERM): pass it on at once.
            stop_process(server, timeout_s=DASHBOARD_STOP_S)
            print("dashboard stopped", file=sys.stderr)
            return 0
        finally:
            if server.poll() is None:  # a second signal while stopping, or an error above
                server.kill()
                server.wait()


def serve_command(args, paths: DataPaths) -> int:
    from flows import launch
    from flows import serve as served
    from flows.config import load_config
    from tasks.errors import BadInput

    if not 0 < args.port < 65536:
        raise ValueError(f"--port must be between 1 and 65535, got {args.port}")
    if args.workers < 0:
        raise ValueError(f"--workers must be 0 or more, got {args.workers}")
    watch = None
    if args.watch is None:
        for flag in ("adversary", "adversary_colour", "cron", "every", "until"):
            if getattr(args, flag) is not None:
                raise ValueError(f"--{flag.replace('_', '-')} goes with --watch DIR")
    else:
        if not args.watch.is_dir():
            raise BadInput(str(args.watch), "is not a directory (--watch)")
        if not args.adversary:
            raise ValueError("--watch needs --adversary NAME: whom the videos dropped there show")
        if args.every is not None and not args.every > 0:
            raise ValueError(f"--every must be a positive number of seconds, got {args.every}")
        watch = served.Watch(
            args.watch,
            args.adversary,
            args.adversary_colour,
            args.cron or served.DEFAULT_CRON,
            args.every,
            args.until,
        )
    running = launch.served_api(paths)
    if running is not None:
        raise ValueError(f"{paths.root} is served already, at {running.removesuffix('/api')}")
    own_server = "PREFECT_API_URL" not in os.environ
    if own_server and not served.port_free(args.port):
        raise ValueError(f"--port {args.port} is in use (another server?): choose another")
    config = load_config(args.config, overrides(args)).as_dict()
    # Set before Prefect is first imported (just below): it reads its settings then. A URL the
    # user set names their own server: serve there, start none.
    api = os.environ.setdefault("PREFECT_API_URL", f"http://127.0.0.1:{args.port}/api")
    for name, value in served.RUNNER_SETTINGS.items():
        os.environ.setdefault(name, value)
    deployments = served.deployments(paths, config, watch)
    # SIGTERM stops it as Ctrl-C does, the server included (below); once serving, SIGTERM
    # cancels the runner instead (see serve_deployments).
    server = None
    with sigterm_as_ctrl_c():
        try:
            if own_server:
                written = served.server_log_size(paths)
                server = served.start_server(paths, args.port)
                if not served.wait_until_up(api, server):
                    print(served.log_tail(paths), file=sys.stderr)
                    why = served.startup_failure(
                        paths, written, server.poll() is not None, served.SERVER_START_S
                    )
                    print(f"ringside: error: {why}", file=sys.stderr)
                    return EXIT_FAILED
            ui = api.removesuffix("/api")
            launch.write_served(paths, launch.Served(api, ui, os.getpid()))
            print(f"Prefect UI: {ui} (Ctrl-C stops serving)", flush=True)
            print(
                f"serving {launch.PIPELINE_FLOW}/{launch.DEPLOYMENT} on {paths.root}: "
                "`ringside schedule`, the dashboard's reruns and the UI's Run start it",
                flush=True,
            )
            if watch is not None:
                when = f"every {watch.every_s:g} s" if watch.every_s else f"on cron '{watch.cron}'"
                print(
                    f"watching {watch.folder.resolve()} {when} for new videos of {watch.adversary}",
                    flush=True,
                )
            served.serve_deployments(deployments, paths, args.workers)
        except (KeyboardInterrupt, SystemExit):  # SystemExit: Prefect's own SIGTERM handler
            pass
        finally:
            launch.clear_served(paths, os.getpid())
            if server is not None:
                served.stop_process(server)
    print("serving stopped", file=sys.stderr)
    return 0


def worker_command(args, paths: DataPaths) -> int:
    from flows import launch
    from flows import serve as served
    from tasks.errors import BadInput

    if args.limit < 1:
        raise ValueError(f"--limit must be at least 1, got {args.limit}")
    api = os.environ.get("PREFECT_API_URL")
    if api is None:
        raise BadInput(
            str(paths.root),
            f"{launch.NO_SERVER} (on another machine: set PREFECT_API_URL to its server)",
        )
    served.ensure_work_pool()
    with sigterm_as_ctrl_c():
        worker = served.start_worker(paths, args.limit)
        print(
            f"taking runs from work pool '{served.WORK_POOL}' of {api}, {args.limit} at a time "
            f"(log: {served.worker_log(paths)}; Ctrl-C stops)",
            flush=True,
        )
        try:
            worker.wait()
        except KeyboardInterrupt:
            pass
        finally:
            served.stop_workers([worker])
    print("worker stopped", file=sys.stderr)
    return 0


def schedule_command(args, paths: DataPaths) -> int:
    from datetime import datetime

    from flows import launch
    from flows import serve as served
    from flows.config import load_config
    from tasks.ingest.probe import check_file

    # Cheap checks first: a mistyped path or time fails before anything is submitted.
    for video in args.videos:
        check_file(Path(video))
    at = served.parse_when(args.at, now=datetime.now().astimezone())
    config = load_config(args.config, overrides(args))
    parameters = launch.run_parameters(
        paths,
        args.videos,
        args.adversary,
        args.adversary_colour,
        args.notes,
        config.as_dict(),
        until=args.until,
    )
    run_id = launch.submit_run(
        paths, parameters, at=None if args.at.strip().lower() == "now" else at
    )
    ui = (launch.served_api(paths) or "").removesuffix("/api")
    url = f"{ui}/runs/flow-run/{run_id}"
    if args.json:
        print(json.dumps({"flow_run_id": run_id, "scheduled_time": at.isoformat(), "url": url}))
    else:
        print(f"flow run {run_id} runs at {at:%Y-%m-%d %H:%M:%S %Z}")
        print(f"follow it at {url}")
    return 0


def spar_server_command(args, paths: DataPaths) -> int:
    import asyncio
    import secrets
    import signal

    from flows.spar_server import PATH, SparServer, needs_token, run_server, warm_up
    from tasks.opponent.folder import load_opponent

    if not 0 <= args.port < 65536:
        raise ValueError(f"--port must be between 0 and 65535, got {args.port}")
    if args.max_sessions < 1:
        raise ValueError(f"--max-sessions must be at least 1, got {args.max_sessions}")
    token = args.token
    if token is None and needs_token(args.host):
        token = secrets.token_urlsafe(16)
    opponent = load_opponent(args.opponent)
    partner = None if args.partner is None else load_opponent(args.partner)
    warm_up(opponent, partner)
    server = SparServer(
        opponent, assets=paths.assets, token=token, partner=partner, max_sessions=args.max_sessions
    )

    def ready(port: int) -> None:
        query = f"?token={token}" if token else ""
        print(
            f"spar server: ws://{args.host}:{port}{PATH}  viewer: http://{args.host}:{port}/"
            f"{query}  (opponent {opponent.folder}; Ctrl-C stops it)",
            flush=True,
        )

    async def serve() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(signum, stop.set)
        await run_server(server, args.host, args.port, ready, stop)

    asyncio.run(serve())
    print("spar server stopped", file=sys.stderr)
    return 0
