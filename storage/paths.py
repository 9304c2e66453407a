"""The data directory's layout, resolved from ``RINGSIDE_DATA`` (default ``./data``), and where the
results live: the data directory's DuckDB file, or a DuckLake catalog on PostgreSQL whose data
and artifacts are on a folder every machine reaches (``RINGSIDE_RESULTS``, ``RINGSIDE_SHARED``)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

# A DuckLake catalog on PostgreSQL: this prefix, then libpq's key=value connection string.
LAKE_PREFIX = "ducklake:postgres:"


@dataclass(frozen=True)
class Lake:
    """Results in a DuckLake catalog on PostgreSQL (``catalog``: libpq's ``dbname=... host=...``
    string), their Parquet files and the artifact store under ``shared``, a folder every
    machine mounts at the same path. `storage.db.connect` opens it as it opens a DuckDB file."""

    catalog: str
    shared: Path

    @property
    def data_path(self) -> Path:
        return self.shared / "lake"

    def exists(self) -> bool:
        """Whether a writer has made the lake yet (its data folder is made once its first
        attach has made the catalog)."""
        return self.data_path.is_dir()

    def __str__(self) -> str:
        return f"{LAKE_PREFIX}{self.catalog}"


def lake_of(results: str, shared: str | Path | None) -> Lake:
    """The `Lake` a ``--results`` setting names; ValueError in one line if it names none."""
    if not results.startswith(LAKE_PREFIX) or not results[len(LAKE_PREFIX) :].strip():
        raise ValueError(
            f"--results {results!r}: expected {LAKE_PREFIX}dbname=NAME host=HOST port=PORT "
            "user=USER (a DuckLake catalog on PostgreSQL)"
        )
    if not shared:
        raise ValueError(
            "--results with a DuckLake catalog needs --shared DIR (or $RINGSIDE_SHARED): the "
            "folder every machine reaches, for the lake's data files and the artifacts"
        )
    return Lake(results[len(LAKE_PREFIX) :].strip(), Path(shared).expanduser().resolve())


@dataclass(frozen=True)
class DataPaths:
    """Every place Ringside writes, under one root; assets may live elsewhere (shared), and the
    results and artifacts in a `Lake`."""

    root: Path
    assets: Path
    lake: Lake | None = None

    @property
    def db(self) -> Path | Lake:
        """The results: the data directory's DuckDB file, or the lake."""
        return self.lake if self.lake is not None else self.root / "ringside.duckdb"

    @property
    def artifacts(self) -> Path:
        if self.lake is not None:
            return self.lake.shared / "artifacts"
        return self.root / "artifacts"

    @property
    def prefect_home(self) -> Path:
        return self.root / "prefect"

    @property
    def claims(self) -> Path:
        """Lock files of the outputs being computed now (`storage.claims`; with a lake, the
        claims are PostgreSQL's advisory locks instead)."""
        return self.root / "claims"


def data_paths(
    root: str | Path | None = None, results: str | None = None, shared: str | Path | None = None
) -> DataPaths:
    """The data directory: ``root`` if given, else ``$RINGSIDE_DATA``, else ``./data``.

    Assets (weights, sample videos) are under it too, unless ``$RINGSIDE_ASSETS`` names another
    folder, so several data directories can share one copy. The results are in the data
    directory unless ``results`` (else ``$RINGSIDE_RESULTS``) names a DuckLake catalog, with
    ``shared`` (else ``$RINGSIDE_SHARED``) its folder.
    """
    chosen = Path(root if root is not None else os.environ.get("RINGSIDE_DATA", "data"))
    root_path = chosen.expanduser().resolve()
    assets = os.environ.get("RINGSIDE_ASSETS")
    results = results if results is not None else os.environ.get("RINGSIDE_RESULTS", "")
    shared = shared if shared is not None else os.environ.get("RINGSIDE_SHARED")
    return DataPaths(
        root_path,
        Path(assets).expanduser().resolve() if assets else root_path / "assets",
        lake_of(results, shared) if results else None,
    )
