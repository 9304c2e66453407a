"""Typed, frozen stage configs: defaults in code, documented in ``ringside.toml``, overridable.

Each stage's config is a frozen dataclass whose fields are declared with :func:`setting`, so every
field carries its documentation. :func:`build` turns a mapping (a TOML table with command-line
overrides applied) into the dataclass and rejects unknown names and wrongly typed values.
"""

from __future__ import annotations

import dataclasses
import tomllib
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")


def setting(default: Any, help: str) -> Any:
    """A config field with its default and the sentence that documents it."""
    return dataclasses.field(default=default, metadata={"help": help})


def field_types(cls: type) -> dict[str, type]:
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls)}


def coerce(value: Any, kind: type, name: str) -> Any:
    """``value`` as ``kind`` (bool, int, float or str), accepting command-line text too."""
    if kind is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "false", "1", "0", "yes", "no"):
            return value.lower() in ("true", "1", "yes")
    elif kind is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, str):
            try:
                return int(value)
            except ValueError:
                pass
    elif kind is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
        if isinstance(value, str):
            try:
                return float(value)
            except ValueError:
                pass
    elif kind is str:
        if isinstance(value, str):
            return value
    else:
        raise TypeError(f"{name}: unsupported config type {kind}")
    raise ValueError(f"{name} must be {kind.__name__}, got {value!r}")


def build(cls: type[T], values: Mapping[str, Any], *, section: str) -> T:
    """An instance of the config dataclass ``cls`` from ``values``; unknown names are errors."""
    types = field_types(cls)
    unknown = sorted(set(values) - set(types))
    if unknown:
        raise ValueError(f"[{section}] has no setting {', '.join(unknown)}; known: {sorted(types)}")
    kwargs = {name: coerce(v, types[name], f"{section}.{name}") for name, v in values.items()}
    return cls(**kwargs)


def read_toml(path: Path) -> dict[str, Any]:
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: config file not found") from None
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{path}: not valid TOML ({error})") from None


def apply_overrides(tables: Mapping[str, Any], overrides: list[str]) -> dict[str, dict]:
    """``tables`` with ``SECTION.NAME=VALUE`` overrides applied (values stay text until built)."""
    result = {section: dict(values) for section, values in tables.items()}
    for item in overrides:
        dotted, sep, value = item.partition("=")
        section, dot, name = dotted.partition(".")
        if not sep or not dot or not section or not name:
            raise ValueError(f"override must look like SECTION.NAME=VALUE, got {item!r}")
        result.setdefault(section, {})[name.replace("-", "_")] = value
    return result
