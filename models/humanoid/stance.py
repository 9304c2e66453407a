"""A fighter's guard: a standing pose like the footage's that the body holds without help.

The humanoid stands on its own, held only by its PD targets, in its rest pose (knees locked
straight) and in few other poses: holding any frame of the demo's footage, or of DeepMimic's
punch clip, fell in 1-2 s. A boxer stands with bent knees, though, and a policy that starts
straight-legged never finds them (the discriminators told every such policy from the footage
by the knee angle first). `guard_pose` builds a pose between the two, measured to stand:

- spine, neck and arms: each hinge's median over the fighter's frames (its usual guard);
- knees: both at the median flexion of its frames' knees;
- hips and ankles: feet flat and pelvis level, the knee's flexion split between hip and ankle
  so that the whole body's centre of mass lies `COM_AHEAD_M` in front of the ankles.

Measured with the sample's fighters and the default body (16-32 arenas, 30 s, N(0, 0.02) on
every target, 120 Hz): with the centre of mass 1 cm in front of the ankles every trial stood,
at the footage's knee flexion (0.26 and 0.39 rad) and at half of it; at 0 cm or 2 cm some fell,
at 5-7 cm (over the middle of the sole, 7 cm in front of the ankle) all fell in 2-3 s.
"""

from __future__ import annotations

import mujoco
import numpy as np
from scipy.optimize import brentq

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.kinematics import HINGE_NAMES, NQ, NUM_ACTUATED

COM_AHEAD_M = 0.01
_HINGE = {name: i for i, name in enumerate(HINGE_NAMES)}
SIDES = ("left", "right")
LEG_HINGES = slice(_HINGE["right_hip_y"], NUM_ACTUATED)  # hips, knees and ankles: the last 14


def _com_ahead(model: mujoco.MjModel, data: mujoco.MjData, hinges: np.ndarray) -> float:
    """How far (m) the centre of mass lies in front of the ankles, the body upright at the
    origin facing +x with ``hinges``."""
    data.qpos[:] = 0.0
    data.qpos[3] = 1.0
    data.qpos[7:] = hinges
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    ankles = np.mean([data.xpos[model.body(f"{side}_foot").id, 0] for side in SIDES])
    return float(data.subtree_com[1, 0] - ankles)


def _legs(hinges: np.ndarray, knee: float, hip_share: float) -> np.ndarray:
    """``hinges`` with both legs bent by ``knee``, ``hip_share`` of it at the hip and the rest at
    the ankle (so the foot stays parallel to the pelvis), no sideways or twisting angles."""
    out = hinges.copy()
    out[LEG_HINGES] = 0.0
    for side in SIDES:
        out[_HINGE[f"{side}_hip_y"]] = -hip_share * knee
        out[_HINGE[f"{side}_knee"]] = knee
        out[_HINGE[f"{side}_ankle_y"]] = -(1.0 - hip_share) * knee
    return out


def guard_pose(bones: BoneLengths, qpos: np.ndarray) -> np.ndarray:
    """The fighter's guard (module docstring): 28 hinge angles in `JOINT_LAYOUT` order.

    Args:
        bones: the fighter's bones.
        qpos: (M, 35) its frames (e.g. its reference frames from the footage).
    """
    q = np.asarray(qpos, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != NQ or len(q) == 0 or not np.isfinite(q).all():
        raise ValueError(f"qpos must be finite with shape (M >= 1, {NQ}), got {q.shape}")
    hinges = np.median(q[:, 7:], axis=0)
    knees = q[:, [7 + _HINGE[f"{side}_knee"] for side in SIDES]]
    knee = float(np.clip(np.median(knees), 0.0, None))
    if knee == 0.0:
        return _legs(hinges, 0.0, 0.5)
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(bones))
    data = mujoco.MjData(model)

    def error(share: float) -> float:
        return _com_ahead(model, data, _legs(hinges, knee, share)) - COM_AHEAD_M

    # More of the bend at the hip moves the pelvis back over the heels: the error falls with
    # the share, so a sign change brackets the one balanced split.
    low, high = -1.0, 2.0
    if error(low) * error(high) > 0:
        share = low if abs(error(low)) < abs(error(high)) else high
    else:
        share = brentq(error, low, high, xtol=1e-4)
    return _legs(hinges, knee, share)
