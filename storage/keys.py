"""Cache keys: a stage output is keyed by its stage, config, code version and upstream keys."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Mapping
from importlib import import_module
from pathlib import Path
from typing import Any


def _plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


def stable_json(value: Any) -> str:
    """JSON with sorted keys: equal values always give equal text (dataclasses become objects)."""
    return json.dumps(_plain(value), sort_keys=True, separators=(",", ":"))


def digest(value: Any) -> str:
    return hashlib.sha256(stable_json(value).encode()).hexdigest()


def code_version(*packages: str) -> str:
    """Hash of every Python source file of ``packages`` (a name may also be a single module):
    editing a stage's code changes its keys."""
    h = hashlib.sha256()
    for package in packages:
        source = Path(import_module(package).__file__)
        folder = source.parent
        paths = sorted(folder.rglob("*.py")) if source.name == "__init__.py" else [source]
        for path in paths:
            h.update(f"{package}/{path.relative_to(folder).as_posix()}".encode())
            h.update(b"\0")
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


def stage_key(stage: str, config: Any, code: str, upstream: Mapping[str, Any]) -> str:
    """The key of a stage output: equal inputs give equal keys."""
    return digest({"stage": stage, "config": config, "code": code, "upstream": upstream})[:24]
