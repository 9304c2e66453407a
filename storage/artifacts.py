"""Content-addressed artifact store: large binaries live in files named by their SHA-256.

DuckDB rows refer to an artifact by its name, ``<sha256><suffix>``; the same bytes are stored once.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

from storage.files import write_atomic


def artifact_name(data: bytes, suffix: str = "") -> str:
    if suffix and not suffix.startswith("."):
        raise ValueError(f"suffix must start with '.', got {suffix!r}")
    return hashlib.sha256(data).hexdigest() + suffix


# A SHA-256 in hex and an optional suffix of letters and digits: nothing that leaves the store.
NAME = re.compile(r"[0-9a-f]{64}(\.[A-Za-z0-9]{1,16})?")


class NotAnArtifact(ValueError):
    """A name that is not an artifact's (a path, say): refused, never read, served or deleted."""


def artifact_path(root: Path, name: str) -> Path:
    """Where the artifact ``name`` lives: ``root/ab/abcdef….suffix``. NotAnArtifact for any
    other name (the database may name only files inside the store)."""
    if not isinstance(name, str) or NAME.fullmatch(name) is None:
        raise NotAnArtifact(f"not an artifact name: {name!r} (refused: outside the store)")
    return root / name[:2] / name


def put_bytes(root: Path, data: bytes, suffix: str = "") -> str:
    """Store ``data`` and return its artifact name; storing the same bytes again is a no-op."""
    name = artifact_name(data, suffix)
    target = artifact_path(root, name)
    if target.exists():
        return name
    write_atomic(target, data)
    return name


def read_bytes(root: Path, name: str) -> bytes:
    path = artifact_path(root, name)
    if not path.exists():
        raise FileNotFoundError(f"artifact {name} is missing from {root}")
    data = path.read_bytes()
    if hashlib.sha256(data).hexdigest() != name[:64]:
        raise ValueError(f"artifact {path} is corrupt: its bytes do not match its name")
    return data
