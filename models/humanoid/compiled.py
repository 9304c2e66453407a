"""The boxer humanoid in a compiled MuJoCo model: where its bodies, sites and joints are
(`humanoid_index`; a model may hold two fighters) and MuJoCo's forward kinematics of them.
Conventions as in `models.humanoid.kinematics`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from models.humanoid.kinematics import (
    BLAZEPOSE_TO_SITE,
    BODY_NAMES,
    JOINT_LAYOUT,
    NQ,
    NUM_BODIES,
    NV,
    SITE_NAMES,
)
from models.humanoid.observations import (
    FRAME_WIDTH,
    BodyState,
    body_state_from_frames,
    world_frames,
)
from models.pose.types import BLAZEPOSE_33


@dataclass(frozen=True, eq=False)
class HumanoidIndex:
    """Where one humanoid lives in a compiled model (a model may hold two fighters).

    Attributes:
        prefix: the name prefix its MJCF elements carry ("" for a lone boxer).
        body_ids: (15,) MuJoCo body ids in BODY_NAMES order.
        site_ids: (S,) MuJoCo site ids in SITE_NAMES order.
        qpos_start: qpos address of its root free joint; its qpos is qpos[start:start + 35].
        qvel_start: qvel address of its root; its qvel is qvel[start:start + 34].
    """

    prefix: str
    body_ids: np.ndarray
    site_ids: np.ndarray
    qpos_start: int
    qvel_start: int

    @property
    def qpos(self) -> slice:
        """Its slice of the model's qpos."""
        return slice(self.qpos_start, self.qpos_start + NQ)

    @property
    def qvel(self) -> slice:
        """Its slice of the model's qvel."""
        return slice(self.qvel_start, self.qvel_start + NV)


def humanoid_index(model: mujoco.MjModel, *, prefix: str = "") -> HumanoidIndex:
    """Find the boxer whose element names start with `prefix` in `model`.

    Raises:
        ValueError: naming the missing element, or if its joints are not laid out
            as JOINT_LAYOUT says.
    """

    def find(kind: mujoco.mjtObj, name: str, what: str) -> int:
        index = mujoco.mj_name2id(model, kind, prefix + name)
        if index < 0:
            raise ValueError(f"model has no {what} {prefix + name!r} (prefix={prefix!r})")
        return index

    body_ids = np.array([find(mujoco.mjtObj.mjOBJ_BODY, b, "body") for b in BODY_NAMES])
    site_ids = np.array([find(mujoco.mjtObj.mjOBJ_SITE, s, "site") for s in SITE_NAMES])
    root = find(mujoco.mjtObj.mjOBJ_JOINT, "root", "joint")
    if model.jnt_type[root] != mujoco.mjtJoint.mjJNT_FREE:
        raise ValueError(f"joint {prefix + 'root'!r} must be a free joint")
    qpos_start = int(model.jnt_qposadr[root])
    qvel_start = int(model.jnt_dofadr[root])
    for joint in JOINT_LAYOUT:
        for k, hinge in enumerate(joint.hinges):
            j = find(mujoco.mjtObj.mjOBJ_JOINT, hinge, "joint")
            if int(model.jnt_qposadr[j]) != qpos_start + joint.qpos_start + k:
                raise ValueError(
                    f"joint {prefix + hinge!r} is at qpos {model.jnt_qposadr[j]}, "
                    f"expected {qpos_start + joint.qpos_start + k} (JOINT_LAYOUT order)"
                )
    return HumanoidIndex(prefix, body_ids, site_ids, qpos_start, qvel_start)


def _check_qpos(model: mujoco.MjModel, qpos: np.ndarray, batched: bool) -> np.ndarray:
    q = np.asarray(qpos, dtype=np.float64)
    want = (None, model.nq) if batched else (model.nq,)
    if q.ndim != len(want) or q.shape[-1] != model.nq:
        shape = "(T, nq)" if batched else "(nq,)"
        raise ValueError(f"qpos must have shape {shape} with nq={model.nq}, got {q.shape}")
    return q


def forward_kinematics(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    *,
    prefix: str = "",
    data: mujoco.MjData | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Positions and rotations of one humanoid's 15 bodies for a model configuration.

    Args:
        model: a compiled model holding the boxer named by `prefix`.
        qpos: (nq,) the whole model's qpos.
        prefix: the boxer's name prefix.
        data: optional scratch MjData for `model` (its qpos is overwritten).

    Returns:
        (15, 3) body origins (joint centres; the pelvis origin is mid-hip) in
        metres and (15, 3, 3) body rotations, world frame.
    """
    q = _check_qpos(model, qpos, batched=False)
    index = humanoid_index(model, prefix=prefix)
    data = mujoco.MjData(model) if data is None else data
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    ids = index.body_ids
    return data.xpos[ids].copy(), data.xmat[ids].reshape(-1, 3, 3).copy()


def forward_kinematics_batch(
    model: mujoco.MjModel, qpos: np.ndarray, *, prefix: str = ""
) -> tuple[np.ndarray, np.ndarray]:
    """`forward_kinematics` over T frames.

    Args:
        model: a compiled model holding the boxer named by `prefix`.
        qpos: (T, nq) model configurations.
        prefix: the boxer's name prefix.

    Returns:
        (T, 15, 3) body positions and (T, 15, 3, 3) body rotations, world frame.
    """
    q = _check_qpos(model, qpos, batched=True)
    ids = humanoid_index(model, prefix=prefix).body_ids
    data = mujoco.MjData(model)
    pos = np.empty((len(q), NUM_BODIES, 3))
    rot = np.empty((len(q), NUM_BODIES, 3, 3))
    for t, frame in enumerate(q):
        data.qpos[:] = frame
        mujoco.mj_kinematics(model, data)
        pos[t] = data.xpos[ids]
        rot[t] = data.xmat[ids].reshape(-1, 3, 3)
    return pos, rot


def site_positions(
    model: mujoco.MjModel, data: mujoco.MjData, *, prefix: str = ""
) -> dict[str, np.ndarray]:
    """World positions of one humanoid's sites, by unprefixed site name.

    `data` must hold current kinematics (after mj_kinematics, mj_forward or a step).

    Returns:
        {site name: (3,) position in metres} for every name in SITE_NAMES.
    """
    ids = humanoid_index(model, prefix=prefix).site_ids
    return {name: data.site_xpos[i].copy() for name, i in zip(SITE_NAMES, ids, strict=True)}


def keypoint_positions(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    *,
    keypoints: Sequence[str] = BLAZEPOSE_33,
    prefix: str = "",
) -> np.ndarray:
    """The humanoid's version of a skeleton: its sites for the named keypoints.

    Lets a 3D skeleton (BlazePose-33 or COCO-17 order) be compared point by point
    with the humanoid; several landmarks share a site (see BLAZEPOSE_TO_SITE).

    Args:
        model: a compiled model holding the boxer named by `prefix`.
        qpos: (T, nq) or (nq,) model configurations.
        keypoints: keypoint names, each a key of BLAZEPOSE_TO_SITE (COCO-17 names are).
        prefix: the boxer's name prefix.

    Returns:
        (T, K, 3) or (K, 3) site positions in metres, world frame.
    """
    unknown = [k for k in keypoints if k not in BLAZEPOSE_TO_SITE]
    if unknown:
        raise ValueError(f"keypoints has names with no humanoid site: {unknown}")
    single = np.ndim(qpos) == 1
    q = _check_qpos(model, np.atleast_2d(qpos), batched=True)
    index = humanoid_index(model, prefix=prefix)
    site_of = dict(zip(SITE_NAMES, index.site_ids, strict=True))
    ids = np.array([site_of[BLAZEPOSE_TO_SITE[k]] for k in keypoints], dtype=int)
    data = mujoco.MjData(model)
    out = np.empty((len(q), len(ids), 3))
    for t, frame in enumerate(q):
        data.qpos[:] = frame
        mujoco.mj_kinematics(model, data)
        out[t] = data.site_xpos[ids]
    return out[0] if single else out


def velocities(model: mujoco.MjModel, qpos: np.ndarray, fps: float) -> np.ndarray:
    """qvel (T, nv) by central differences of qpos with `mj_differentiatePos` (one-sided at
    the ends; zeros for a single frame)."""
    frames = len(qpos)
    qvel = np.zeros((frames, model.nv))
    if frames < 2:
        return qvel
    dt = 1.0 / fps
    for frame in range(frames):
        a, b = max(frame - 1, 0), min(frame + 1, frames - 1)
        mujoco.mj_differentiatePos(model, qvel[frame], (b - a) * dt, qpos[a], qpos[b])
    return qvel


def body_state(model: mujoco.MjModel, data: mujoco.MjData, index: HumanoidIndex) -> BodyState:
    """The current state of one humanoid of a simulation (`world_frames` says what `data` must
    hold)."""
    return body_state_from_frames(world_frames(model, data), index.body_ids)


def body_states(
    model: mujoco.MjModel, qpos: np.ndarray, qvel: np.ndarray, index: HumanoidIndex
) -> BodyState:
    """States of one humanoid over T recorded frames.

    Args:
        model: a compiled model holding the humanoid `index` describes.
        qpos: (T, nq) model positions.
        qvel: (T, nv) model velocities.
        index: from `humanoid_index`.

    Returns:
        BodyState with leading shape (T,).
    """
    qpos = np.asarray(qpos, dtype=np.float64)
    qvel = np.asarray(qvel, dtype=np.float64)
    if qpos.ndim != 2 or qpos.shape[1] != model.nq:
        raise ValueError(f"qpos must have shape (T, {model.nq}), got {qpos.shape}")
    if qvel.shape != (len(qpos), model.nv):
        raise ValueError(f"qvel must have shape ({len(qpos)}, {model.nv}), got {qvel.shape}")
    data = mujoco.MjData(model)
    frames = np.empty((len(qpos), model.nbody, FRAME_WIDTH))
    for t in range(len(qpos)):
        data.qpos[:] = qpos[t]
        data.qvel[:] = qvel[t]
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        mujoco.mj_comVel(model, data)
        world_frames(model, data, frames[t])
    return body_state_from_frames(frames, index.body_ids)
