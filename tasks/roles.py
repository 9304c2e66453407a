"""The two fighters every stage speaks of, and their agent numbers in the dataset and training."""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

ROLES: tuple[str, str] = ("adversary", "opponent")
AGENTS: Mapping[str, int] = MappingProxyType({role: agent for agent, role in enumerate(ROLES)})
