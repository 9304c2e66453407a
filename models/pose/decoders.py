"""Pose model outputs to keypoints: SimCC (RTMPose: Li et al., "SimCC: a Simple Coordinate
Classification Perspective for Human Pose Estimation", ECCV 2022) and heatmaps (SimpleBaseline,
HRNet, ViTPose), chosen by the shapes of a model's outputs (`models.pose.onnx_backend`).

Coordinates are model-input pixels (x right, y down). Shape letters: K pose joints, h x w
heatmap, r SimCC split ratio.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Protocol

import numpy as np


def decode_simcc(
    simcc_x: np.ndarray, simcc_y: np.ndarray, split_ratio: float
) -> tuple[np.ndarray, np.ndarray]:
    """SimCC decoding (Li et al. 2022, Sec. 3.2): each axis's argmax bin / split ratio.

    Confidence is the smaller of the two axes' maximum values, RTMPose's
    published choice (mmpose's `get_simcc_maximum`): a joint is only as sure
    as its less certain coordinate. The values are the raw head outputs, not
    softmaxed, as in mmpose. Unlike mmpose, a joint whose maximum is <= 0
    keeps its argmax position (mmpose sets it to -1); its confidence says it
    is not there.

    Args:
        simcc_x: (K, W * r) x-axis classification.
        simcc_y: (K, H * r) y-axis classification.
        split_ratio: r, bins per input pixel.

    Returns:
        keypoints (K, 2) in input pixels, confidence (K,).
    """
    simcc_x = np.asarray(simcc_x)
    simcc_y = np.asarray(simcc_y)
    if simcc_x.ndim != 2 or simcc_y.ndim != 2 or len(simcc_x) != len(simcc_y):
        raise ValueError(
            f"simcc_x and simcc_y must have shapes (K, W * r) and (K, H * r), "
            f"got {simcc_x.shape} and {simcc_y.shape}"
        )
    keypoints = np.stack([simcc_x.argmax(axis=1), simcc_y.argmax(axis=1)], axis=1) / split_ratio
    confidence = np.minimum(simcc_x.max(axis=1), simcc_y.max(axis=1)).astype(np.float64)
    return keypoints, confidence


def decode_heatmap(heatmaps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heatmap decoding with the classic quarter-pixel refinement.

    The argmax (x, y) moves 0.25 px towards the higher of its two neighbours on
    each axis (Newell et al., "Stacked Hourglass Networks", ECCV 2016; the
    SimpleBaseline / HRNet / ViTPose default); no move on an axis where the
    peak sits on the heatmap's edge or both neighbours are equal.
    Confidence is the peak value.

    Args:
        heatmaps: (K, h, w).

    Returns:
        keypoints (K, 2) in heatmap pixels (x, y), confidence (K,).
    """
    heatmaps = np.asarray(heatmaps, dtype=np.float64)
    if heatmaps.ndim != 3:
        raise ValueError(f"heatmaps must have shape (K, h, w), got {heatmaps.shape}")
    num_joints, height, width = heatmaps.shape
    flat = heatmaps.reshape(num_joints, -1)
    ys, xs = np.unravel_index(flat.argmax(axis=1), (height, width))
    confidence = flat.max(axis=1)
    joints = np.arange(num_joints)
    # Neighbour differences, 0 where a neighbour is missing (peak on the edge).
    inner_x = (xs > 0) & (xs < width - 1)
    inner_y = (ys > 0) & (ys < height - 1)
    right = heatmaps[joints, ys, np.minimum(xs + 1, width - 1)]
    left = heatmaps[joints, ys, np.maximum(xs - 1, 0)]
    below = heatmaps[joints, np.minimum(ys + 1, height - 1), xs]
    above = heatmaps[joints, np.maximum(ys - 1, 0), xs]
    dx = np.where(inner_x, np.sign(right - left), 0.0)
    dy = np.where(inner_y, np.sign(below - above), 0.0)
    keypoints = np.stack([xs + 0.25 * dx, ys + 0.25 * dy], axis=1)
    return keypoints, confidence


@dataclass(frozen=True)
class OutputSpec:
    """One model output as the model file declares it: name and shape (None = dynamic)."""

    name: str
    shape: tuple[int | None, ...]


class PoseDecoder(Protocol):
    """Turns a pose model's outputs into joints in input pixels."""

    def select_outputs(
        self, outputs: Sequence[OutputSpec], input_size: tuple[int, int], num_joints: int
    ) -> tuple[str, ...]:
        """Names of the outputs to fetch, in `decode`'s order; ValueError if none fit."""
        ...

    def decode(
        self, outputs: Sequence[np.ndarray], input_size: tuple[int, int]
    ) -> tuple[np.ndarray, np.ndarray]:
        """The selected outputs (batch dim dropped) -> (K, 2) input pixels, (K,) confidence."""
        ...


def dims_fit(shape: tuple[int | None, ...], want: tuple[int | None, ...]) -> bool:
    """Whether a declared shape can be `want` (None on either side matches anything)."""
    return len(shape) == len(want) and all(
        s is None or w is None or s == w for s, w in zip(shape, want, strict=True)
    )


def describe_outputs(outputs: Sequence[OutputSpec]) -> str:
    return ", ".join(
        f"{o.name} ({', '.join('*' if d is None else str(d) for d in o.shape)})" for o in outputs
    )


@dataclass(frozen=True)
class SimccDecoder:
    """RTMPose's SimCC outputs `simcc_x` (1, K, W * r) and `simcc_y` (1, K, H * r).

    Attributes:
        split_ratio: r, SimCC bins per input pixel (2.0 for every RTMPose).
    """

    split_ratio: float = 2.0

    def select_outputs(
        self, outputs: Sequence[OutputSpec], input_size: tuple[int, int], num_joints: int
    ) -> tuple[str, ...]:
        """`simcc_x` and `simcc_y` by name, else the model's only two rank-3 outputs, in order."""
        by_name = {o.name: o for o in outputs}
        if "simcc_x" in by_name and "simcc_y" in by_name:
            chosen = [by_name["simcc_x"], by_name["simcc_y"]]
        else:
            chosen = [o for o in outputs if len(o.shape) == 3]
        width, height = input_size
        want = [
            (1, num_joints, round(width * self.split_ratio)),
            (1, num_joints, round(height * self.split_ratio)),
        ]
        if len(chosen) != 2 or not all(
            dims_fit(o.shape, w) for o, w in zip(chosen, want, strict=True)
        ):
            raise ValueError(
                f"expected SimCC outputs simcc_x {want[0]} and simcc_y {want[1]} "
                f"(K = {num_joints} joints, r = {self.split_ratio}); the model has "
                f"{describe_outputs(outputs)}"
            )
        return tuple(o.name for o in chosen)

    def decode(
        self, outputs: Sequence[np.ndarray], input_size: tuple[int, int]
    ) -> tuple[np.ndarray, np.ndarray]:
        """[(K, W * r), (K, H * r)] -> (K, 2) input pixels, (K,) confidence (`decode_simcc`)."""
        simcc_x, simcc_y = outputs
        return decode_simcc(simcc_x, simcc_y, self.split_ratio)


@dataclass(frozen=True)
class HeatmapDecoder:
    """A heatmap head's one output (1, K, h, w) (SimpleBaseline, HRNet, ViTPose)."""

    def select_outputs(
        self, outputs: Sequence[OutputSpec], input_size: tuple[int, int], num_joints: int
    ) -> tuple[str, ...]:
        """The model's only rank-4 output."""
        chosen = [o for o in outputs if len(o.shape) == 4]
        if len(chosen) != 1 or not dims_fit(chosen[0].shape, (1, num_joints, None, None)):
            raise ValueError(
                f"expected one heatmap output (1, {num_joints}, h, w); the model has "
                f"{describe_outputs(outputs)}"
            )
        return (chosen[0].name,)

    def decode(
        self, outputs: Sequence[np.ndarray], input_size: tuple[int, int]
    ) -> tuple[np.ndarray, np.ndarray]:
        """[(K, h, w)] -> (K, 2) input pixels, (K,) confidence.

        Heatmap pixel (x, y) is input pixel (x * W / w, y * H / h), as in mmpose.
        """
        (heatmaps,) = outputs
        keypoints, confidence = decode_heatmap(heatmaps)
        height, width = np.shape(heatmaps)[1:]
        factor = np.asarray(input_size, dtype=np.float64) / [width, height]
        return keypoints * factor, confidence


# RTMPose's decoder (every published RTMPose uses r = 2) and the heatmap one.
RTMPOSE_DECODER = SimccDecoder(split_ratio=2.0)


HEATMAP_DECODER = HeatmapDecoder()


# Named pose decoders, for configs and CLI options.
POSE_DECODERS: Mapping[str, PoseDecoder] = MappingProxyType(
    {"simcc": RTMPOSE_DECODER, "heatmap": HEATMAP_DECODER}
)
