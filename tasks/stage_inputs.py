"""What each stage's plan is given besides its subject: one field per upstream output it reads
(that output's key). Apart from `tasks.registry`, which declares the stages with them, so that a
stage's `task.py` can import its inputs' type without importing every stage's config."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Declared:
    """Ingest's inputs: who the analyst declared the adversary to be."""

    adversary: str
    adversary_colour: str | None = None
    notes: str | None = None


@dataclass(frozen=True)
class PoseInputs:
    ingest: str  # the ingest output's key


@dataclass(frozen=True)
class LiftInputs:
    ingest: str
    pose: str


@dataclass(frozen=True)
class DatasetInputs:
    ingest: str
    lift: str


@dataclass(frozen=True)
class NoInputs:
    """The inputs of a stage whose subject is its only upstream output (training's dataset,
    evaluation's run)."""
