"""The ``ringside`` command: process, status, rerun, metrics, assets, dashboard, serve, demo,
postgres.

Prefect reads its settings when it is first imported, so ``main`` points Prefect at the data
directory before anything imports it.
"""

from __future__ import annotations

import argparse
import atexit
import logging
import os
import signal
import sys
import traceback
from collections.abc import Callable
from pathlib import Path

from flows.cli.environment import (
    EXIT_BAD_INPUT,
    EXIT_FAILED,
    make_prefect_home,
    prefect_settings_of_this_command,
    prepare_environment,
)
from flows.cli.parser import build_parser
from flows.cli.pipeline import (
    datasets_command,
    demo_command,
    metrics_command,
    pick_command,
    process_command,
    rerun_command,
    status_command,
)
from flows.cli.postgres import postgres_command
from flows.cli.servers import (
    dashboard_command,
    schedule_command,
    serve_command,
    spar_server_command,
    worker_command,
)
from flows.cli.synthetic import synthetic_adversary_command
from flows.cli.training import (
    curves_command,
    evaluate_command,
    export_command,
    export_motion_command,
    spar_command,
    train_command,
)
from flows.cli.upkeep import (
    assets_command,
    backup_command,
    calibrate_command,
    check_command,
    config_command,
    restore_command,
)
from storage.paths import DataPaths

# Each command's function, called with its parsed arguments and the data directory.
COMMANDS: dict[str, Callable[[argparse.Namespace, DataPaths], int]] = {
    "process": process_command,
    "status": status_command,
    "rerun": rerun_command,
    "pick": pick_command,
    "metrics": metrics_command,
    "datasets": datasets_command,
    "synthetic-adversary": synthetic_adversary_command,
    "demo": demo_command,
    "train": train_command,
    "curves": curves_command,
    "export": export_command,
    "evaluate": evaluate_command,
    "export-motion": export_motion_command,
    "spar": spar_command,
    "spar-server": spar_server_command,
    "check": check_command,
    "backup": backup_command,
    "restore": restore_command,
    "assets": assets_command,
    "calibrate": calibrate_command,
    "config": config_command,
    "dashboard": dashboard_command,
    "serve": serve_command,
    "postgres": postgres_command,
    "worker": worker_command,
    "schedule": schedule_command,
}


def main(argv: list[str] | None = None) -> int:
    """One `ringside` command; the environment is left as it was found, so that a command run
    in-process (the tests, a notebook) does not hand its Prefect server (PREFECT_API_URL) to the
    next one as if the user had set it, and the server it started is stopped when it returns."""
    saved = dict(os.environ)
    try:
        return _command(sys.argv[1:] if argv is None else argv)
    finally:
        from flows.serve import stop_private_servers

        stop_private_servers()
        os.environ.clear()
        os.environ.update(saved)


def _command(raw: list[str]) -> int:
    # Settings must be in the environment before the parser's imports reach Prefect.
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--data", type=Path)
    pre.add_argument("--results")
    pre.add_argument("--shared", type=Path)
    pre.add_argument("--verbose", action="store_true")
    known, _ = pre.parse_known_args(raw)
    from storage.paths import data_paths

    try:
        paths = data_paths(known.data, known.results, known.shared)
    except ValueError as error:
        print(f"ringside: error: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    prepare_environment(paths, verbose=known.verbose)
    with prefect_settings_of_this_command():
        return _dispatch(raw, paths)


def _dispatch(raw: list[str], paths: DataPaths) -> int:
    args = build_parser().parse_args(raw)
    make_prefect_home()
    import duckdb

    from flows.serve import ServerError
    from storage.assets import AssetError
    from storage.db import CatalogUnreachable, DatabaseBusy, damaged_database, error_line
    from tasks.errors import BadInput

    try:
        return COMMANDS[args.command](args, paths)
    except (BadInput, ValueError, FileNotFoundError) as error:
        print(f"ringside: error: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except (AssetError, CatalogUnreachable, DatabaseBusy, ServerError) as error:
        print(f"ringside: error: {error}", file=sys.stderr)
        return EXIT_FAILED
    except duckdb.Error as error:
        if not damaged_database(error):
            raise
        print(
            f"ringside: error: the database {paths.db} is damaged "
            f"({error_line(error)}); `ringside check` says what is affected "
            "and `ringside check --repair` recomputes it",
            file=sys.stderr,
        )
        return EXIT_FAILED


def run() -> None:
    """The `ringside` command: `main`, and after an error an exit without the interpreter's
    teardown. An error raised inside a Prefect flow stays referenced by Prefect's run state,
    frames and all, until that teardown, where DuckDB's bindings then report each object
    still alive: dozens of `nanobind: leaked ...` lines after our one line. The logs are sent
    to Prefect's server first, then the exit handlers run (Prefect stops that server in one)."""
    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _interrupt)
    from storage.db import Interrupted

    try:
        code = main()
    except Interrupted:
        # The signal reached a DuckDB query, which swallowed the handler's stop (inside a flow,
        # Prefect's): the stop is ours to make, as `_stop` makes any other.
        _stop(signal.SIGTERM, None)
    except Exception:
        # A bug: its traceback, then out without the teardown's leak lines (above).
        traceback.print_exc()
        _leave(1)
    if code != 0:
        _leave(code)
    sys.exit(code)


def _leave(code: int) -> None:
    sys.stdout.flush()
    sys.stderr.flush()
    logging.shutdown()
    atexit._run_exitfuncs()
    os._exit(code)


# What stopped the command, for its last line: SIGTERM, or Ctrl-C (`_interrupt`).
_stopped_by = {"signal": signal.SIGTERM}


def _interrupt(_signum: int, _frame) -> None:
    """Ctrl-C ends a command as SIGTERM does. Inside a flow Prefect turns SIGTERM into marking
    the flow runs Crashed and cancelling their tasks; a KeyboardInterrupt, it lets wait for the
    pose stage's chunk threads (a Ctrl-C once took over 30 s to end a command). `serve` and
    `dashboard` take SIGTERM as their own stop, as they took Ctrl-C."""
    _stopped_by["signal"] = signal.SIGINT
    os.kill(os.getpid(), signal.SIGTERM)


def _stop(_signum: int, _frame) -> None:
    """SIGTERM: one line, Prefect's server stopped, out (what is committed stays committed)."""
    how = "Ctrl-C" if _stopped_by["signal"] == signal.SIGINT else "SIGTERM"
    print(
        f"ringside: error: stopped by {how}; the same command picks up where it stopped",
        file=sys.stderr,
    )
    _leave(128 + _stopped_by["signal"])
