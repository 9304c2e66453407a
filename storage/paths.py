"""The data directory's layout, resolved from ``RINGSIDE_DATA`` (default ``./data``)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class DataPaths:
    """Every place Ringside writes, under one root."""

    root: Path

    @property
    def db(self) -> Path:
        return self.root / "ringside.duckdb"

    @property
    def artifacts(self) -> Path:
        return self.root / "artifacts"

    @property
    def assets(self) -> Path:
        return self.root / "assets"

    @property
    def prefect_home(self) -> Path:
        return self.root / "prefect"


def data_paths(root: str | Path | None = None) -> DataPaths:
    """The data directory: ``root`` if given, else ``$RINGSIDE_DATA``, else ``./data``."""
    chosen = root if root is not None else os.environ.get("RINGSIDE_DATA", "data")
    return DataPaths(Path(chosen).expanduser().resolve())
