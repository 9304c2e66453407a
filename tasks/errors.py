"""Errors a user can act on: each names what is wrong and where."""

from __future__ import annotations


class BadInput(ValueError):
    """Input Ringside cannot use, such as a file that is not a readable video.

    ``str()`` is one line, ``"<source>: <problem>"``. The arguments are kept as ``args`` so the
    error survives pickling (Prefect stores a failed task's exception).
    """

    def __init__(self, source: str, problem: str):
        super().__init__(source, problem)
        self.source = source
        self.problem = problem

    def __str__(self) -> str:
        return f"{self.source}: {self.problem}"
