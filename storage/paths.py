"""The data directory's layout, resolved from ``RINGSIDE_DATA`` (default ``./data``)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class DataPaths:
    """Every place Ringside writes, under one root; assets may live elsewhere (shared)."""

    root: Path
    assets: Path

    @property
    def db(self) -> Path:
        return self.root / "ringside.duckdb"

    @property
    def artifacts(self) -> Path:
        return self.root / "artifacts"

    @property
    def prefect_home(self) -> Path:
        return self.root / "prefect"

    @property
    def claims(self) -> Path:
        """Lock files of the outputs being computed now (`storage.claims`)."""
        return self.root / "claims"


def data_paths(root: str | Path | None = None) -> DataPaths:
    """The data directory: ``root`` if given, else ``$RINGSIDE_DATA``, else ``./data``.

    Assets (weights, sample videos) are under it too, unless ``$RINGSIDE_ASSETS`` names another
    folder, so several data directories can share one copy.
    """
    chosen = Path(root if root is not None else os.environ.get("RINGSIDE_DATA", "data"))
    root_path = chosen.expanduser().resolve()
    assets = os.environ.get("RINGSIDE_ASSETS")
    return DataPaths(
        root_path, Path(assets).expanduser().resolve() if assets else root_path / "assets"
    )
