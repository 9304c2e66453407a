"""How a setting is declared: a dataclass field with its default and the sentence that documents
it. Stage configs (`tasks`) and model configs (`models.maaip.config`) both use it, so that
`ringside config` documents every one."""

from __future__ import annotations

import dataclasses
from typing import Any


def setting(default: Any, help: str) -> Any:
    """A config field with its default and the sentence that documents it."""
    return dataclasses.field(default=default, metadata={"help": help})
