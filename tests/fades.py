"""Fades to black, for the cut detectors' tests and `benchmarks/cut_detectors.py` (which imports
this file directly; it has no side effects, unlike conftest)."""

from __future__ import annotations

import numpy as np


def fade_gains(n: int, start: int, length: int, hold: int = 4) -> np.ndarray:
    """Gains of ``n`` frames fading to black over ``length`` frames from ``start``, ``hold``
    black frames (the first is the fade's last), then fading back over ``length``."""
    t = np.arange(n) - start
    out = (1 - (t + 1) / length).clip(0, 1) * (t < length)
    back = ((t - length - hold + 1) / length).clip(0, 1)
    return np.where(t < 0, 1.0, np.where(t < length + hold - 1, out, back))


def faded(frames: list[np.ndarray], gains) -> list[np.ndarray]:
    """Each frame's brightness times its gain (0: black)."""
    return [
        np.clip(f.astype(np.float32) * g, 0, 255).astype(np.uint8)
        for f, g in zip(frames, gains, strict=True)
    ]
