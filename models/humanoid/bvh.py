"""The boxer humanoid's motion as Biovision Hierarchy (BVH) text, for animation tools.

The hierarchy is the humanoid's own skeleton (`models.humanoid.boxer`, scaled to the fighter's
bones): one joint per body in BODY_NAMES, each OFFSET the body's origin in its parent's frame at
qpos0, an End Site at the centre of each leaf body's last geom (head, gloves, feet). The pelvis
carries position and rotation channels, every other joint three rotation channels; the hands are
welded and the elbows and knees are hinges, so some channels stay 0, but every joint has the
same three (readers disagree on partial channel lists).

Conventions of the file, chosen for what Blender, MotionBuilder and most BVH readers assume:
- y up, x forward, z to the fighter's right (`Y_UP_TO_Z_UP` turns it back into Ringside's z up);
  Blender's importer with its defaults (forward -Z, up Y) puts the fighter back in Ringside's
  world axes.
- Centimetres (import into Blender with scale 0.01 for metres).
- Rotation channels in the order Z X Y: a 3-DoF joint's hinges y, x, z (Ry Rx Rz, kinematics
  module) become exactly Rz Rx Ry in the y-up frame, so the file's Euler angles are the hinge
  angles (y negated) and share their singularity, which the joint limits keep out of reach.
  Each channel is unwrapped over time (a whole turn added to one Euler angle is the same pose),
  so tools that interpolate keys do not spin a joint the long way round.
"""

from __future__ import annotations

import warnings

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.compiled import humanoid_index
from models.humanoid.kinematics import (
    BODY_NAMES,
    NQ,
    PARENTS,
    ROOT_POS,
    Y_UP_TO_Z_UP,
    joint_local_rotations,
)

CENTIMETRES = 100.0
# Rotation channels, applied in this order (intrinsic): R = Rz Rx Ry.
ROTATION_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")
POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
_Z_UP_TO_Y_UP = Y_UP_TO_Z_UP.T


def _children(parent: int) -> list[int]:
    return [i for i, p in enumerate(PARENTS) if p == parent]


def skeleton(bones: BoneLengths) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """The hierarchy's geometry in the file's frame and units.

    Returns:
        (15, 3) each joint's OFFSET from its parent (the root's is 0), and {leaf body index:
        (3,) its End Site offset}.
    """
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(bones))
    ids = humanoid_index(model).body_ids
    offsets = model.body_pos[ids] @ _Z_UP_TO_Y_UP.T * CENTIMETRES
    offsets[0] = 0.0
    ends = {}
    for i, body in enumerate(ids):
        if not _children(i):
            last = np.flatnonzero(model.geom_bodyid == body)[-1]
            ends[i] = _Z_UP_TO_Y_UP @ model.geom_pos[last] * CENTIMETRES
    return offsets, ends


def channels(qpos: np.ndarray) -> np.ndarray:
    """The motion section's values for one humanoid's qpos.

    Args:
        qpos: (T, 35) one humanoid's qpos in Ringside's world (metres, z up).

    Returns:
        (T, 6 + 3 * 14) per frame: the root's position (cm) then every joint's Z X Y
        rotation (degrees), in BODY_NAMES order, y up.
    """
    q = np.asarray(qpos, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != NQ or not len(q):
        raise ValueError(f"qpos must have shape (T >= 1, {NQ}), got {q.shape}")
    if not np.isfinite(q).all():
        raise ValueError("qpos must be finite")
    local = _Z_UP_TO_Y_UP @ joint_local_rotations(q) @ Y_UP_TO_Z_UP
    with warnings.catch_warnings():
        # A root rolled onto its side meets the Z X Y order's gimbal lock: scipy then picks
        # one of the equivalent angle triples, which is still the same rotation.
        warnings.filterwarnings("ignore", "Gimbal lock detected", UserWarning)
        euler = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_euler("ZXY", degrees=True)
    euler = np.unwrap(euler.reshape(len(q), -1), axis=0, period=360.0)
    position = q[:, ROOT_POS] @ _Z_UP_TO_Y_UP.T * CENTIMETRES
    return np.concatenate([position, euler], axis=1)


def _fmt(values: np.ndarray) -> str:
    return " ".join(f"{v:.6f}" for v in values)


def _joint_lines(index: int, offsets: np.ndarray, ends: dict[int, np.ndarray], depth: int):
    pad = "  " * depth
    kind = "ROOT" if index == 0 else "JOINT"
    listed = (*POSITION_CHANNELS, *ROTATION_CHANNELS) if index == 0 else ROTATION_CHANNELS
    yield f"{pad}{kind} {BODY_NAMES[index]}"
    yield f"{pad}{{"
    yield f"{pad}  OFFSET {_fmt(offsets[index])}"
    yield f"{pad}  CHANNELS {len(listed)} {' '.join(listed)}"
    for child in _children(index):
        yield from _joint_lines(child, offsets, ends, depth + 1)
    if index in ends:
        yield f"{pad}  End Site"
        yield f"{pad}  {{"
        yield f"{pad}    OFFSET {_fmt(ends[index])}"
        yield f"{pad}  }}"
    yield f"{pad}}}"


def bvh_text(bones: BoneLengths, qpos: np.ndarray, fps: float) -> str:
    """One fighter's motion as a BVH document (module docstring).

    Args:
        bones: the fighter's bone lengths (the humanoid it was lifted or simulated on).
        qpos: (T, 35) its qpos per frame, Ringside's world.
        fps: frames per second (30 for lifted motion and simulated bouts).
    """
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    offsets, ends = skeleton(bones)
    values = channels(qpos)
    lines = ["HIERARCHY", *_joint_lines(0, offsets, ends, 0), "MOTION"]
    lines += [f"Frames: {len(values)}", f"Frame Time: {1.0 / fps:.8f}"]
    lines += [_fmt(row) for row in values]
    return "\n".join(lines) + "\n"
