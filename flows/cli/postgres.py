"""`ringside postgres`: a PostgreSQL cluster for Prefect's server, in the data directory."""

from __future__ import annotations

import argparse
import sys

from flows.cli.environment import EXIT_FAILED
from storage.paths import DataPaths


def postgres_command(args: argparse.Namespace, paths: DataPaths) -> int:
    """Start the cluster (made the first time) and print the setting `ringside serve` needs, on
    stdout alone (`export "$(ringside postgres)"` works); or stop it (--stop)."""
    from flows.postgres import PostgresError, connection_url, results_setting, start, stop

    folder = paths.root / "postgres"
    try:
        if args.stop:
            was_running = stop(folder)
            print(f"PostgreSQL in {folder} {'stopped' if was_running else 'was not running'}")
            return 0
        port, was_running = start(folder, args.port)
    except PostgresError as error:
        print(f"ringside: error: {error}", file=sys.stderr)
        return EXIT_FAILED
    how = "was already running" if was_running else "started"
    if args.lake:
        print(f"PostgreSQL in {folder} {how} on 127.0.0.1:{port}; for --results:", file=sys.stderr)
        print(f"RINGSIDE_RESULTS={results_setting(port)}")
        return 0
    print(
        f"PostgreSQL in {folder} {how} on 127.0.0.1:{port}; for `ringside serve`:", file=sys.stderr
    )
    print(f"PREFECT_API_DATABASE_CONNECTION_URL={connection_url(port)}")
    return 0
