"""`python -m flows.cli`: the `ringside` command."""

from flows.cli import run

run()
