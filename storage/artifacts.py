"""Content-addressed artifact store: large binaries live in files named by their SHA-256.

DuckDB rows refer to an artifact by its name, ``<sha256><suffix>``; the same bytes are stored once.
"""

from __future__ import annotations

import hashlib
import re
import time
from pathlib import Path

from storage.files import sha256_file, write_atomic

# Where corrupt files are moved, inside the store: `root/quarantine/<name>.<time>`. Its name is
# no artifact's two-letter folder, so nothing in it is ever read as an artifact.
QUARANTINE = "quarantine"


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
    """Store ``data`` and return its artifact name; storing the same bytes again is a no-op,
    unless the file there is corrupt: it is quarantined and replaced."""
    name = artifact_name(data, suffix)
    target = artifact_path(root, name)
    if sound(root, name):
        return name
    write_atomic(target, data)
    return name


def sound(root: Path, name: str) -> bool:
    """Whether the artifact ``name`` is there with the bytes its name promises; a corrupt file
    is quarantined on the way (so the name reads as missing and is computed again)."""
    path = artifact_path(root, name)
    if not path.exists():
        return False
    if hashes_to_name(path):
        return True
    quarantine(root, path)
    return False


def hashes_to_name(path: Path) -> bool:
    """Whether the artifact file ``path``'s bytes hash to its name, read in blocks (a
    checkpoint may be hundreds of MB)."""
    return sha256_file(path) == path.name[:64]


def quarantine(root: Path, path: Path) -> Path:
    """Move the corrupt file ``path`` of the store ``root`` aside, named with the time, where
    nothing reads it but a person can still look; where it went."""
    aside = root / QUARANTINE / f"{path.name}.{time.strftime('%Y%m%d-%H%M%S')}"
    aside.parent.mkdir(parents=True, exist_ok=True)
    path.replace(aside)
    return aside


def corrupt_files(root: Path) -> list[Path]:
    """Every file of the store ``root`` whose bytes do not hash to its name, whether or not
    the database names it (the pose stage's chunk files are named by Prefect's cache)."""
    if not root.exists():
        return []
    return sorted(
        path for path in root.glob("??/*") if NAME.fullmatch(path.name) and not hashes_to_name(path)
    )


def read_bytes(root: Path, name: str) -> bytes:
    path = artifact_path(root, name)
    if not path.exists():
        raise FileNotFoundError(f"artifact {name} is missing from {root}")
    data = path.read_bytes()
    if hashlib.sha256(data).hexdigest() != name[:64]:
        raise ValueError(f"artifact {path} is corrupt: its bytes do not match its name")
    return data
