"""Checks of refinement's inputs and settings (`tasks.pose.refine`, `tasks.pose.smoothing`,
`tasks.pose.config`), each naming what is wrong."""

from __future__ import annotations

import numpy as np


def checked(
    keypoints: np.ndarray, confidence: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """float64 copies of the inputs after shape and value checks that name the argument."""
    kp = np.array(keypoints, dtype=np.float64, copy=True)
    if kp.ndim != 3 or kp.shape[2] != 2:
        raise ValueError(f"keypoints must have shape (T, J, 2), got {kp.shape}")
    if np.isinf(kp).any():
        raise ValueError("keypoints must be finite or NaN, got inf")
    if confidence is None:
        return kp, None
    conf = np.array(confidence, dtype=np.float64, copy=True)
    if conf.shape != kp.shape[:2]:
        raise ValueError(
            f"confidence must have shape (T, J) = {kp.shape[:2]} to match keypoints, "
            f"got {conf.shape}"
        )
    if not np.isfinite(conf).all() or (conf < 0).any() or (conf > 1).any():
        raise ValueError("confidence must hold values in [0, 1] (use 0 for missing joints)")
    return kp, conf


def check_positive(name: str, value: float) -> None:
    if not value > 0:
        raise ValueError(f"{name} must be > 0, got {value}")


def check_window(name: str, window: int, order: int, *, order_name: str) -> None:
    if order < 0:
        raise ValueError(f"{order_name} must be >= 0, got {order}")
    if window < 1 or window % 2 == 0:
        raise ValueError(f"{name} must be a positive odd number of frames, got {window}")
    if window <= order:
        raise ValueError(f"{name} ({window}) must be larger than {order_name} ({order})")
