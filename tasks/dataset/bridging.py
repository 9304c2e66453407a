"""Short gaps inside a fighter's motion, bridged rather than cut.

A gate that drops one or two steps (a frame the lift did not believe, a step the dataset's
guard left out) would otherwise cut a clip in two, and both halves may fall under
`dataset.min_clip_s`: on a 1.7 s video two dropped steps threw away the only interaction clip.
A gap of at most `dataset.max_bridge_steps` steps, inside one shot and one split, is filled by
interpolating the steps either side of it: the root's position linearly, its rotation by slerp,
each hinge angle linearly. Filled like that, DeepMimic's punch, kick, run and walk are off by a
median 0.7 cm and a 95th percentile of 5.8 cm over the filled keypoints at 2 steps, under the
lift's own 6.4-7.7 cm per joint on the sample (PA-MPJPE, benchmarks/lift_multiview.py); at 3
steps the 95th percentile, 8.6 cm, passes it (benchmarks/gap_bridging.py), hence 2 by default.
What a bridge cannot give back is a fast hand: a gap over a punch's extension cuts its peak (the
punch's glove up to 22 cm off at 2 steps), so the dataset counts the steps it filled
(`steps_bridged`).
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from models.humanoid.compiled import keypoint_positions, velocities
from models.humanoid.motion import RATE, FighterMotion


def gaps(
    steps: np.ndarray, shot_of_step: np.ndarray, validation_from: int, max_steps: int
) -> list[tuple[int, int]]:
    """The gaps ``[a, b)`` of missing steps that may be bridged: at most ``max_steps`` long,
    with a present step either side in the same shot and the same split."""
    steps = np.asarray(steps)
    if max_steps < 1 or len(steps) < 2:
        return []
    found = []
    for i in np.flatnonzero(np.diff(steps) > 1):
        before, after = int(steps[i]), int(steps[i + 1])
        same_split = (before >= validation_from) == (after >= validation_from)
        if (
            after - before - 1 <= max_steps
            and shot_of_step[i] == shot_of_step[i + 1]
            and same_split
        ):
            found.append((before + 1, after))
    return found


def interpolate_qpos(before: np.ndarray, after: np.ndarray, count: int) -> np.ndarray:
    """(count, 35) poses evenly between two (35,) poses, both left out: the root linearly and
    by slerp, the 28 hinge angles linearly."""
    u = (np.arange(1, count + 1) / (count + 1))[:, None]
    out = np.empty((count, len(before)))
    out[:, :3] = before[:3] * (1 - u) + after[:3] * u
    keys = Rotation.from_quat(np.stack([before[3:7], after[3:7]]), scalar_first=True)
    out[:, 3:7] = Slerp([0.0, 1.0], keys)(u[:, 0]).as_quat(scalar_first=True)
    out[:, 7:] = before[7:] * (1 - u) + after[7:] * u
    return out


def bridge(
    motion: FighterMotion, spans: list[tuple[int, int]], model: mujoco.MjModel
) -> FighterMotion:
    """``motion`` with the steps of each gap ``[a, b)`` in ``spans`` filled: poses by
    :func:`interpolate_qpos`, keypoints from the humanoid's sites, a foot in contact where it
    is on both sides, and the velocities of the filled steps and of the steps either side
    taken again by central differences, as the lift takes them."""
    if not spans:
        return motion
    steps = np.union1d(motion.step, np.concatenate([np.arange(a, b) for a, b in spans]))
    grid = {name: motion.on_grid(getattr(motion, name), int(steps[-1]) + 1) for name in
            ("qpos", "qvel", "joints", "contacts")}  # fmt: skip
    for a, b in spans:
        grid["qpos"][a:b] = interpolate_qpos(grid["qpos"][a - 1], grid["qpos"][b], b - a)
        grid["joints"][a:b] = keypoint_positions(model, grid["qpos"][a:b])
        grid["contacts"][a:b] = grid["contacts"][a - 1] & grid["contacts"][b]
    present = ~np.isnan(grid["qpos"][:, 0])
    for a, b in spans:
        # Steps a-1 and b take their central differences again, from a-2 and b+1 where those
        # are present (where not, the lift took one-sided differences there too).
        lo = a - 2 if a >= 2 and present[a - 2] else a - 1
        hi = b + 1 if b + 1 < len(present) and present[b + 1] else b
        window = velocities(model, grid["qpos"][lo : hi + 1], RATE)
        grid["qvel"][a - 1 : b + 1] = window[a - 1 - lo : b + 1 - lo]
    return dataclasses.replace(motion, step=steps, **{k: v[steps] for k, v in grid.items()})
