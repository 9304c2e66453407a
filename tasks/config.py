"""Typed, frozen stage configs: defaults in code, documented in ``ringside.toml``, overridable.

Each stage's config is a frozen dataclass whose fields are declared with :func:`setting`, so every
field carries its documentation. :func:`build` turns a mapping (a TOML table with command-line
overrides applied) into the dataclass and rejects unknown names and wrongly typed values.
"""

from __future__ import annotations

import copy
import dataclasses
import tomllib
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")


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
    """An instance of the config dataclass ``cls`` from ``values``; unknown names are errors.

    A field whose type is itself a config dataclass is built from a sub-table of the same name.
    """
    types = field_types(cls)
    unknown = sorted(set(values) - set(types))
    if unknown:
        raise ValueError(f"[{section}] has no setting {', '.join(unknown)}; known: {sorted(types)}")
    kwargs = {}
    for name, value in values.items():
        where = f"{section}.{name}"
        if dataclasses.is_dataclass(types[name]):
            if not isinstance(value, Mapping):
                raise ValueError(f"{where} must be a table of settings, got {value!r}")
            kwargs[name] = build(types[name], value, section=where)
        else:
            kwargs[name] = coerce(value, types[name], where)
    built = cls(**kwargs)
    # A config with settings by name (`TrainConfig.preset`) takes them as it is built.
    return built.with_preset() if hasattr(built, "with_preset") else built


def leaf_fields(cls: type, prefix: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], Any]]:
    """Every scalar setting of ``cls``, nested ones included, as (path, dataclass field)."""
    types = field_types(cls)
    found = []
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(types[f.name]):
            found += leaf_fields(types[f.name], (*prefix, f.name))
        else:
            found.append(((*prefix, f.name), f))
    return found


def read_toml(path: Path) -> dict[str, Any]:
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: config file not found") from None
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{path}: not valid TOML ({error})") from None


def apply_overrides(tables: Mapping[str, Any], overrides: list[str]) -> dict[str, dict]:
    """``tables`` with ``SECTION[.SUB].NAME=VALUE`` overrides applied (values stay text until
    built)."""
    result = copy.deepcopy(dict(tables))
    for item in overrides:
        dotted, sep, value = item.partition("=")
        path = [part.replace("-", "_") for part in dotted.split(".")]
        if not sep or len(path) < 2 or not all(path):
            raise ValueError(f"override must look like SECTION.NAME=VALUE, got {item!r}")
        table = result
        for part in path[:-1]:
            table = table.setdefault(part, {})
            if not isinstance(table, dict):
                raise ValueError(f"override {item!r}: {part} is a setting, not a table")
        table[path[-1]] = value
    return result


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return repr(value)


def _wrap(text: str, width: int = 98) -> list[str]:
    lines, line = [], ""
    for word in text.split():
        if line and len(line) + 1 + len(word) > width:
            lines.append(line)
            line = word
        else:
            line = f"{line} {word}".strip()
    return [*lines, line] if line else lines


def defaults_toml(sections: Mapping[str, type], header: str) -> str:
    """Every setting at its default, each under its documentation, as TOML text."""
    out = [f"# {line}" if line else "#" for line in header.splitlines()]

    def table(name: str, cls: type) -> None:
        out.extend(["", f"[{name}]"])
        nested = []
        types = field_types(cls)
        for f in dataclasses.fields(cls):
            if dataclasses.is_dataclass(types[f.name]):
                nested.append((f"{name}.{f.name}", types[f.name]))
                continue
            out.extend(f"# {line}" for line in _wrap(f.metadata["help"]))
            out.append(f"{f.name} = {_toml_value(f.default)}")
        for sub_name, sub_cls in nested:
            table(sub_name, sub_cls)

    for name, cls in sections.items():
        table(name, cls)
    return "\n".join(out) + "\n"
