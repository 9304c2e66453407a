"""Kinematics of the 15-body boxer humanoid: layout, rotations, observation frames, keypoints
(NumPy, rotation conversions through scipy's `Rotation`; MuJoCo's own forward kinematics of a
compiled model is `models.humanoid.compiled`).

The body follows MAAIP (Younes et al., "MAAIP: Multi-Agent Adversarial Interaction
Priors for imitation from fighting demonstrations for physics-based characters",
PACMCGIT 6(3), 2023, §4.2) and the thesis it comes from (Younes, PhD thesis, 2023,
§1.1.1): 15 rigid bodies, a free root at the pelvis, 3-DoF joints at the abdomen,
neck, shoulders, hips and ankles, 1-DoF elbows and knees, fixed hands; 28 actuated
degrees of freedom.

Conventions (all of Ringside's humanoid code):
- World: metres, z up. At qpos0 the humanoid stands facing +x, its left side
  towards +y, and every body frame is aligned with the world frame, so a body's
  rotation is the rotation of its segment away from that rest pose.
- Quaternions are (w, x, y, z), as in MuJoCo.
- A 3-DoF joint is three MuJoCo hinges on one body, about the body's y, x and
  z axes in that order, so its local rotation is Ry(a) @ Rx(b) @ Rz(c) (MuJoCo
  composes a body's joints in declaration order; tested). With the limbs
  hanging along z at rest, y is flexion, x ab/adduction and z the twist about
  the limb. The chain is singular only where |b| = 90 deg (limb pointing
  straight sideways), which the joint limits in `models.humanoid.boxer` keep
  out of reach; an x-first order would put the singularity at a straight jab.
- A 1-DoF joint is one hinge: the elbow about -y and the knee about +y, so
  positive angles are flexion for both.
- qpos of one humanoid (35): root position (3), root quaternion (4), then the
  28 hinge angles in `JOINT_LAYOUT` order. qvel (34): root linear velocity in
  the world frame (3), root angular velocity in the pelvis frame (3) (MuJoCo's
  free-joint convention), then the 28 hinge velocities. Actuators (28) are in
  the same order as the hinge angles.

Shape letters: T frames, N bodies (15 unless stated), K keypoints.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
from array_api_compat import array_namespace, device, is_torch_array

from models.pose.types import BLAZEPOSE_33, COCO_17

# --------------------------------------------------------------------------
# Layout
# --------------------------------------------------------------------------

# The 15 bodies in MuJoCo's body order (depth first, as the MJCF nests them).
BODY_NAMES: tuple[str, ...] = (
    "pelvis",
    "torso",
    "head",
    "right_upper_arm",
    "right_lower_arm",
    "right_hand",
    "left_upper_arm",
    "left_lower_arm",
    "left_hand",
    "right_thigh",
    "right_shin",
    "right_foot",
    "left_thigh",
    "left_shin",
    "left_foot",
)
NUM_BODIES = len(BODY_NAMES)
ROOT_BODY = "pelvis"

# Index of each body's parent in BODY_NAMES (-1 for the root).
PARENTS: tuple[int, ...] = (-1, 0, 1, 1, 3, 4, 1, 6, 7, 0, 9, 10, 0, 12, 13)

# Bodies whose positions MAAIP gives about the opponent (§4.2: head, torso,
# hands and feet).
KEY_BODIES: tuple[str, ...] = (
    "head",
    "torso",
    "right_hand",
    "left_hand",
    "right_foot",
    "left_foot",
)
KEY_BODY_INDEX: np.ndarray = np.array([BODY_NAMES.index(b) for b in KEY_BODIES])

# A y-up world (x forward, y up, z right; DeepMimic's, and BVH's as Ringside writes it) to ours
# (x forward, y left, z up): a proper rotation, +90 deg about x. Vectors map as v_ours = C v,
# rotations as C R C^T; the transpose goes the other way.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

# The root's slots in one humanoid's qpos (position 0:3, quaternion 3:7) and qvel.
ROOT_POS = slice(0, 3)
ROOT_QUAT = slice(3, 7)
ROOT_QVEL = slice(0, 6)
NQ = 7 + 28
NV = 6 + 28
NUM_ACTUATED = 28

_AXES = {
    "x": (1.0, 0.0, 0.0),
    "y": (0.0, 1.0, 0.0),
    "z": (0.0, 0.0, 1.0),
    "-y": (0.0, -1.0, 0.0),
}


@dataclass(frozen=True)
class JointSpec:
    """One actuated joint of the humanoid.

    Attributes:
        name: joint name, e.g. "right_shoulder".
        body: the child body it moves (a name in BODY_NAMES).
        group: gain group ("abdomen", "neck", "shoulder", "elbow", "hip", "knee", "ankle").
        hinges: names of its MuJoCo hinge joints and actuators, in qpos order:
            "<name>_y", "<name>_x", "<name>_z" for 3-DoF joints, "<name>" for 1-DoF.
        axes: unit hinge axes in the body frame, one per hinge.
        qpos_start: index of its first angle in one humanoid's qpos (35).
    """

    name: str
    body: str
    group: str
    hinges: tuple[str, ...]
    axes: tuple[tuple[float, float, float], ...]
    qpos_start: int

    @property
    def dofs(self) -> int:
        """1 or 3."""
        return len(self.hinges)

    @property
    def qpos(self) -> slice:
        """Its slice of one humanoid's qpos (35)."""
        return slice(self.qpos_start, self.qpos_start + self.dofs)

    @property
    def qvel(self) -> slice:
        """Its slice of one humanoid's qvel (34): the free joint has 7 qpos, 6 qvel."""
        return slice(self.qpos_start - 1, self.qpos_start - 1 + self.dofs)

    @property
    def action(self) -> slice:
        """Its slice of the 28 actions / actuators / hinge angles."""
        return slice(self.qpos_start - 7, self.qpos_start - 7 + self.dofs)

    @property
    def body_index(self) -> int:
        """Index of its body in BODY_NAMES."""
        return BODY_NAMES.index(self.body)


def _layout() -> tuple[JointSpec, ...]:
    table = (
        ("abdomen", "torso", "abdomen", "yxz"),
        ("neck", "head", "neck", "yxz"),
        ("right_shoulder", "right_upper_arm", "shoulder", "yxz"),
        ("right_elbow", "right_lower_arm", "elbow", "-y"),
        ("left_shoulder", "left_upper_arm", "shoulder", "yxz"),
        ("left_elbow", "left_lower_arm", "elbow", "-y"),
        ("right_hip", "right_thigh", "hip", "yxz"),
        ("right_knee", "right_shin", "knee", "y"),
        ("right_ankle", "right_foot", "ankle", "yxz"),
        ("left_hip", "left_thigh", "hip", "yxz"),
        ("left_knee", "left_shin", "knee", "y"),
        ("left_ankle", "left_foot", "ankle", "yxz"),
    )
    joints = []
    start = 7
    for name, body, group, axes in table:
        if axes == "yxz":
            hinges = tuple(f"{name}_{a}" for a in "yxz")
            vectors = tuple(_AXES[a] for a in "yxz")
        else:
            hinges = (name,)
            vectors = (_AXES[axes],)
        joints.append(JointSpec(name, body, group, hinges, vectors, start))
        start += len(hinges)
    return tuple(joints)


# The 12 actuated joints in qpos / actuator order (28 hinges in all). The hands
# are welded to the forearms and have no joint.
JOINT_LAYOUT: tuple[JointSpec, ...] = _layout()
HINGE_NAMES: tuple[str, ...] = tuple(h for j in JOINT_LAYOUT for h in j.hinges)
assert len(HINGE_NAMES) == NUM_ACTUATED and JOINT_LAYOUT[-1].qpos.stop == NQ

# --------------------------------------------------------------------------
# Sites and keypoints
# --------------------------------------------------------------------------

# Every MJCF site of the humanoid and the body it lies on. Sites sit where a
# pose estimator puts its keypoints: joint centres, the head's landmarks, the
# knuckles inside the glove ("<side>_hand"), heel and toe tip on the sole.
SITE_BODY: Mapping[str, str] = MappingProxyType(
    {
        "nose": "head",
        "left_eye": "head",
        "right_eye": "head",
        "left_ear": "head",
        "right_ear": "head",
        "mouth_left": "head",
        "mouth_right": "head",
        **{
            f"{side}_{site}": f"{side}_{body}"
            for side in ("left", "right")
            for site, body in (
                ("shoulder", "upper_arm"),
                ("elbow", "lower_arm"),
                ("wrist", "hand"),
                ("hand", "hand"),
                ("hip", "thigh"),
                ("knee", "shin"),
                ("ankle", "foot"),
                ("heel", "foot"),
                ("foot_index", "foot"),
            )
        },
    }
)
SITE_NAMES: tuple[str, ...] = tuple(SITE_BODY)


def _blazepose_site(name: str) -> str:
    for side in ("left", "right"):
        if name in (f"{side}_eye_inner", f"{side}_eye_outer"):
            return f"{side}_eye"
        if name in (f"{side}_pinky", f"{side}_index", f"{side}_thumb"):
            return f"{side}_hand"  # the fingers are balled up inside the glove
    return name


# The site standing for each BlazePose-33 landmark. The eye corners share the
# eye's site and the finger knuckles the glove's knuckle site.
BLAZEPOSE_TO_SITE: Mapping[str, str] = MappingProxyType(
    {name: _blazepose_site(name) for name in BLAZEPOSE_33}
)
# The site standing for each COCO-17 keypoint (the same points under the same names).
COCO17_TO_SITE: Mapping[str, str] = MappingProxyType(
    {name: BLAZEPOSE_TO_SITE[name] for name in COCO_17}
)
# The body each BlazePose-33 / COCO-17 keypoint lies on.
KEYPOINT_TO_BODY: Mapping[str, str] = MappingProxyType(
    {name: SITE_BODY[site] for name, site in BLAZEPOSE_TO_SITE.items()}
)
assert set(BLAZEPOSE_TO_SITE.values()) <= set(SITE_NAMES)

# --------------------------------------------------------------------------
# Rotations (batched over leading dimensions)
# --------------------------------------------------------------------------

# Conversions go through scipy's `Rotation` (its quaternions are scalar-last by default, ours
# scalar-first: `scalar_first=True` throughout; it takes (..., 3, 3) batches as they are).
# Three stay our own code, each with the measured reason beside it: `axis_angle_matrix` and
# `matrix_to_euler_yxz` (scipy's per-call cost slowed the environment's step at its small
# batches), `heading_yaw` (scipy's yaw folds in the roll near the vertical).


def _check_last(name: str, value: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """`value` as float64 (a torch tensor as it is), or ValueError naming `name` unless it ends
    in `shape`."""
    array = value if is_torch_array(value) else np.asarray(value, dtype=np.float64)
    if array.ndim < len(shape) or array.shape[array.ndim - len(shape) :] != shape:
        want = "(..., " + ", ".join(str(s) for s in shape) + ")"
        raise ValueError(f"{name} must have shape {want}, got {array.shape}")
    return array


def _rotation():
    """scipy's `Rotation`, imported on first use: scipy.spatial takes 0.3 s to import, and the
    dashboard reaches this module (the dataset's statistics use `heading_yaw`) without ever
    converting a rotation."""
    from scipy.spatial.transform import Rotation

    return Rotation


def quat_to_matrix(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternions.

    Args:
        quat: (..., 4) quaternions (w, x, y, z); normalised here.

    Returns:
        (..., 3, 3) rotation matrices R, with R @ v rotating v.
    """
    q = _check_last("quat", quat, (4,))
    norm = np.linalg.norm(q, axis=-1)
    if np.any(norm == 0):
        raise ValueError("quat must not contain zero quaternions")
    finite = np.isfinite(norm)
    if finite.all():
        return _rotation().from_quat(q, scalar_first=True).as_matrix()
    # Non-finite quaternions (e.g. frames not lifted) give NaN matrices, as they always have;
    # scipy would refuse them as zero quaternions.
    flat, ok = q.reshape(-1, 4), finite.reshape(-1)
    out = np.full((len(flat), 3, 3), np.nan)
    out[ok] = _rotation().from_quat(flat[ok], scalar_first=True).as_matrix()
    return out.reshape(*q.shape[:-1], 3, 3)


def matrix_to_quat(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) with w >= 0 of rotation matrices (scipy's `Rotation`; at
    w = 0 the first non-zero of x, y, z is positive).

    Args:
        rotation: (..., 3, 3) rotation matrices (taken as given: not re-orthonormalised).

    Returns:
        (..., 4) quaternions.
    """
    r = _check_last("rotation", rotation, (3, 3))
    rotations = _rotation().from_matrix(r, assume_valid=True)
    return rotations.as_quat(canonical=True, scalar_first=True)


def axis_angle_matrix(axis: Sequence[float] | np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotations by `angle` about one fixed axis (Rodrigues' formula).

    Args:
        axis: (3,) rotation axis; normalised here.
        angle: (...) angles in radians: a NumPy array, or a torch tensor (on any device), which
            gives tensors of its dtype there.

    Returns:
        (..., 3, 3) rotation matrices.
    """
    a = np.asarray(axis, dtype=np.float64)
    if a.shape != (3,) or not np.linalg.norm(a) > 0:
        raise ValueError(f"axis must be a non-zero (3,) vector, got {a!r}")
    # Kept rather than scipy's Rotation.from_rotvec(...).as_matrix(), 4-5x slower at the
    # observations' (N, 2) heading frames (13 against 61 us at N = 1, benchmarks/rotations.py),
    # which every environment step builds; and scipy's takes no tensors.
    a = a / np.linalg.norm(a)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    eye = np.eye(3)
    if is_torch_array(angle):
        xp, t = array_namespace(angle), angle[..., None, None]
        k, eye = (xp.asarray(m, dtype=t.dtype, device=device(t)) for m in (k, eye))
    else:
        xp, t = np, np.asarray(angle, dtype=np.float64)[..., None, None]
    return eye + xp.sin(t) * k + (1 - xp.cos(t)) * (k @ k)


def euler_yxz_to_matrix(angles: np.ndarray) -> np.ndarray:
    """Local rotation of a 3-DoF joint from its hinge angles: Ry(a) @ Rx(b) @ Rz(c).

    Args:
        angles: (..., 3) hinge angles (a, b, c) about y, x, z in radians, the
            qpos order of a 3-DoF joint.

    Returns:
        (..., 3, 3) rotation matrices.
    """
    angles = _check_last("angles", angles, (3,))
    return _rotation().from_euler("YXZ", angles).as_matrix()  # upper case: intrinsic


def matrix_to_euler_yxz(rotation: np.ndarray) -> np.ndarray:
    """Hinge angles (a, b, c) with Ry(a) @ Rx(b) @ Rz(c) = rotation; the inverse of
    `euler_yxz_to_matrix`.

    a, c are in (-pi, pi], b in [-pi/2, pi/2]. At the singularity |b| = pi/2 the
    split between a and c is not unique; c = 0 is returned there.

    Args:
        rotation: (..., 3, 3) rotation matrices.

    Returns:
        (..., 3) angles in radians.
    """
    r = _check_last("rotation", rotation, (3, 3))
    # Kept rather than scipy's Rotation.from_matrix(r).as_euler("YXZ"), which goes through a
    # quaternion: 14-19x slower at the step's (N, 2, 8) joints (17 against 235 us at N = 1,
    # benchmarks/rotations.py), where a whole step of the spar's one environment takes under
    # 1 ms. At |b| = pi/2 it too returns c = 0.
    # R = [[ca cc + sa sb sc, sa sb cc - ca sc, sa cb],
    #      [cb sc,            cb cc,            -sb  ],
    #      [ca sb sc - sa cc, sa sc + ca sb cc, ca cb]]
    xp = array_namespace(r)  # NumPy, or torch for Warp's actions on its device
    cb = xp.hypot(r[..., 1, 0], r[..., 1, 1])
    b = xp.atan2(-r[..., 1, 2], cb)
    regular = cb > 1e-9
    zero = xp.zeros_like(cb)
    c = xp.where(regular, xp.atan2(r[..., 1, 0], r[..., 1, 1]), zero)
    # Singular: R00 = ca, R01 = sa sb (with c = 0).
    sb = xp.sign(xp.sin(b))
    a_singular = xp.atan2(r[..., 0, 1] * sb, r[..., 0, 0])
    a = xp.where(regular, xp.atan2(r[..., 0, 2], r[..., 2, 2]), a_singular)
    return xp.stack([a, b, c], axis=-1)


def expmap_to_matrix(expmap: np.ndarray) -> np.ndarray:
    """Rotation matrices of exponential maps (axis times angle, the paper's 3-DoF actions).

    Args:
        expmap: (..., 3) rotation vectors, angle in radians = their norm.

    Returns:
        (..., 3, 3) rotation matrices.
    """
    e = _check_last("expmap", expmap, (3,))
    if not is_torch_array(e):
        return _rotation().from_rotvec(e).as_matrix()
    # A torch tensor (Warp's actions, on its device): Rodrigues' formula on the unnormalised
    # skew matrix E of e, R = I + sin(t)/t E + (1 - cos(t))/t^2 E^2, since scipy takes no
    # tensors; below t = 1e-4 the two factors' Taylor series (their float64 error is 1e-17).
    xp = array_namespace(e)
    t2 = xp.sum(e * e, axis=-1)[..., None, None]
    small = t2 < 1e-8
    t = xp.sqrt(xp.where(small, xp.ones_like(t2), t2))
    first = xp.where(small, 1 - t2 / 6, xp.sin(t) / t)
    second = xp.where(small, 0.5 - t2 / 24, (1 - xp.cos(t)) / (t * t))
    x, y, z = e[..., 0], e[..., 1], e[..., 2]
    zero = xp.zeros_like(x)
    skew = xp.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1)
    skew = xp.reshape(skew, (*e.shape[:-1], 3, 3))
    eye = xp.eye(3, dtype=e.dtype, device=device(e))
    return eye + first * skew + second * (skew @ skew)


def matrix_to_expmap(rotation: np.ndarray) -> np.ndarray:
    """Exponential maps of rotation matrices, angle in [0, pi]; inverse of `expmap_to_matrix`.

    Args:
        rotation: (..., 3, 3) rotation matrices.

    Returns:
        (..., 3) rotation vectors.
    """
    r = _check_last("rotation", rotation, (3, 3))
    return _rotation().from_matrix(r, assume_valid=True).as_rotvec()  # w >= 0: angle <= pi


def tangent_normal(rotation: np.ndarray) -> np.ndarray:
    """The paper's 6D rotation encoding: the rotated tangent (x) and normal (z) axes.

    MAAIP §4.2 encodes each body's rotation "using two 3D vectors corresponding
    to the tangent and normal of its link local coordinate frame" (after AMP,
    Peng et al., SIGGRAPH 2021, §6). Which axes are tangent and normal the papers
    do not say; AMP's released code (`quat_to_tan_norm`) rotates the x axis as the
    tangent and the z axis as the normal, which is what this does: the first and
    third columns of the rotation matrix. Identity gives [1, 0, 0, 0, 0, 1].

    Args:
        rotation: (..., 3, 3) rotation matrices (of a body in whatever frame the
            caller chose, e.g. `local_body_rotations`).

    Returns:
        (..., 6) [tangent, normal].
    """
    r = _check_last("rotation", rotation, (3, 3))
    return array_namespace(r).concat([r[..., :, 0], r[..., :, 2]], axis=-1)


def tangent_normal_to_matrix(tan_norm: np.ndarray) -> np.ndarray:
    """Rotation matrices from [tangent, normal] pairs (Gram-Schmidt); inverse of
    `tangent_normal`, and the nearest rotation for noisy (e.g. predicted) pairs.

    Args:
        tan_norm: (..., 6) tangent (x axis) then normal (z axis); not necessarily
            unit or orthogonal, but not parallel.

    Returns:
        (..., 3, 3) rotation matrices with columns x, y = z cross x, z.
    """
    tn = _check_last("tan_norm", tan_norm, (6,))
    x = tn[..., :3] / np.linalg.norm(tn[..., :3], axis=-1, keepdims=True)
    n = tn[..., 3:]
    z = n - np.sum(n * x, axis=-1, keepdims=True) * x
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


# --------------------------------------------------------------------------
# Heading frame and the paper's local observations
# --------------------------------------------------------------------------


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Angles (radians) into [-pi, pi)."""
    return (np.asarray(angle, dtype=np.float64) + np.pi) % (2 * np.pi) - np.pi


def heading_yaw(root_quat: np.ndarray) -> np.ndarray:
    """Yaw (radians, about +z) of the root's facing direction, its x axis on the floor.

    Args:
        root_quat: (..., 4) root quaternions (w, x, y, z): a NumPy array, or a torch tensor.

    Returns:
        (...) yaw angles in (-pi, pi]; 0 where the x axis points straight up or down.
    """
    q = _check_last("root_quat", root_quat, (4,))
    # Kept rather than scipy's Rotation.from_quat(q).as_euler("ZYX")[..., 0], the same yaw
    # elsewhere: for a fighter on its back (x axis within about 1e-7 rad of vertical) scipy
    # meets gimbal lock and folds the roll into the yaw (1.1 rad for a true 0.7), and it is 4-7x
    # slower at (N, 2) roots (benchmarks/rotations.py).
    xp = array_namespace(q)  # NumPy, or torch for Warp's worlds on their device
    q = q / xp.sqrt(xp.sum(q * q, axis=-1))[..., None]
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return xp.atan2(2 * (x * y + w * z), 1 - 2 * (y * y + z * z))


def heading_frame(root_quat: np.ndarray) -> np.ndarray:
    """The character's local frame's rotation: yaw only, x along the root's facing direction.

    The frame of MAAIP §4.2 and the thesis §1.4.1: origin at the root, x axis
    along the root's facing direction, z along the world's up (the paper writes
    y up for its own simulator).

    Args:
        root_quat: (..., 4) root quaternions (w, x, y, z).

    Returns:
        (..., 3, 3) rotation matrices H = Rz(yaw); a world vector v is H.T @ v
        in the heading frame.
    """
    return axis_angle_matrix(_AXES["z"], heading_yaw(root_quat))


def heading_frame_of_matrix(root_rotation: np.ndarray) -> np.ndarray:
    """`heading_frame` of roots given as rotation matrices (..., 3, 3), such as MuJoCo's xmat:
    the yaw of the x axis on the floor, atan2(R[1, 0], R[0, 0]), without a quaternion between
    (the observations' hot path). NumPy arrays or torch tensors (on any device)."""
    r = _check_last("root_rotation", root_rotation, (3, 3))
    yaw = array_namespace(r).atan2(r[..., 1, 0], r[..., 0, 0])
    return axis_angle_matrix(_AXES["z"], yaw)


def to_heading_frame(vectors: np.ndarray, root_quat: np.ndarray) -> np.ndarray:
    """World-frame vectors (positions relative to the root, velocities) in the heading frame.

    Args:
        vectors: (..., N, 3) world-frame vectors.
        root_quat: (...) leading shape of `vectors`, then 4: root quaternions.

    Returns:
        (..., N, 3) the same vectors rotated by H.T.
    """
    v = _check_last("vectors", vectors, (3,))
    q = _check_last("root_quat", root_quat, (4,))
    if v.ndim < 2 or v.shape[:-2] != q.shape[:-1]:
        raise ValueError(
            f"vectors (..., N, 3) and root_quat (..., 4) must share leading dimensions, "
            f"got {v.shape} and {q.shape}"
        )
    heading = heading_frame(q)
    return np.einsum("...ji,...nj->...ni", heading, v)


def local_body_positions(
    body_pos: np.ndarray, root_pos: np.ndarray, root_quat: np.ndarray
) -> np.ndarray:
    """Body positions in the root's heading frame (MAAIP §4.2, the o^self body block).

    Invariant to translating the whole character and to turning it about z.
    The root's own row is zero; the paper's 42 numbers are rows 1: (14 bodies x 3),
    with the root's height given separately (root_pos[..., 2]).

    Args:
        body_pos: (..., N, 3) world positions in metres.
        root_pos: (..., 3) root (pelvis) world position.
        root_quat: (..., 4) root quaternion (w, x, y, z).

    Returns:
        (..., N, 3) positions relative to the root, in its heading frame.
    """
    p = _check_last("body_pos", body_pos, (3,))
    r = _check_last("root_pos", root_pos, (3,))
    if p.ndim < 2 or p.shape[:-2] != r.shape[:-1]:
        raise ValueError(
            f"body_pos (..., N, 3) and root_pos (..., 3) must share leading dimensions, "
            f"got {p.shape} and {r.shape}"
        )
    return to_heading_frame(p - r[..., None, :], root_quat)


def local_body_rotations(body_rot: np.ndarray, root_quat: np.ndarray) -> np.ndarray:
    """Body rotations in the root's heading frame: H.T @ R.

    Feed the result to `tangent_normal` for the observation's 15 x 6 = 90 rotation
    numbers. (The thesis §1.4.1 expresses them in the character's local frame,
    as here and in AMP's code; MAAIP §4.2's text says "in the link parent's
    frame": `joint_local_rotations` gives those.)

    Args:
        body_rot: (..., N, 3, 3) world rotations.
        root_quat: (..., 4) root quaternions.

    Returns:
        (..., N, 3, 3) rotations.
    """
    r = _check_last("body_rot", body_rot, (3, 3))
    q = _check_last("root_quat", root_quat, (4,))
    if r.ndim < 3 or r.shape[:-3] != q.shape[:-1]:
        raise ValueError(
            f"body_rot (..., N, 3, 3) and root_quat (..., 4) must share leading "
            f"dimensions, got {r.shape} and {q.shape}"
        )
    heading = heading_frame(q)
    return np.einsum("...ji,...njk->...nik", heading, r)


# --------------------------------------------------------------------------
# qpos <-> rotations <-> actions (pure NumPy)
# --------------------------------------------------------------------------


def joint_local_rotations(qpos: np.ndarray) -> np.ndarray:
    """Each body's rotation relative to its parent, from one humanoid's qpos.

    Args:
        qpos: (..., 35) qpos of one humanoid.

    Returns:
        (..., 15, 3, 3): row 0 the root's world rotation, row i > 0 the rotation of
        body i in its parent's frame (identity at qpos0; the hands are welded).
    """
    q = _check_last("qpos", qpos, (NQ,))
    local = np.broadcast_to(np.eye(3), (*q.shape[:-1], NUM_BODIES, 3, 3)).copy()
    local[..., 0, :, :] = quat_to_matrix(q[..., ROOT_QUAT])
    for joint in JOINT_LAYOUT:
        if joint.dofs == 3:
            rot = euler_yxz_to_matrix(q[..., joint.qpos])
        else:
            rot = axis_angle_matrix(joint.axes[0], q[..., joint.qpos_start])
        local[..., joint.body_index, :, :] = rot
    return local


def body_rotations(qpos: np.ndarray) -> np.ndarray:
    """World rotations of the 15 bodies from one humanoid's qpos (rotational FK in NumPy).

    Args:
        qpos: (..., 35) qpos of one humanoid.

    Returns:
        (..., 15, 3, 3) body rotations in the world frame (MuJoCo's xmat).
    """
    local = joint_local_rotations(qpos)
    world = local.copy()
    for i in range(1, NUM_BODIES):
        world[..., i, :, :] = world[..., PARENTS[i], :, :] @ local[..., i, :, :]
    return world


def qpos_from_body_rotations(root_pos: np.ndarray, body_rot: np.ndarray) -> np.ndarray:
    """One humanoid's qpos from its root position and 15 body rotations; inverse of FK.

    Each joint's local rotation R_parent.T @ R_child becomes its hinge angles:
    y-x-z angles for 3-DoF joints (`matrix_to_euler_yxz`), and for 1-DoF joints
    the twist angle about the hinge axis (the part of the rotation the hinge
    can make; the rest is dropped). Joint limits are not applied.

    Args:
        root_pos: (..., 3) pelvis position in metres.
        body_rot: (..., 15, 3, 3) world rotations of the bodies in BODY_NAMES order
            (the hands' rows are not used: they are welded to the forearms).

    Returns:
        (..., 35) qpos.
    """
    p = _check_last("root_pos", root_pos, (3,))
    r = _check_last("body_rot", body_rot, (NUM_BODIES, 3, 3))
    if r.shape[:-3] != p.shape[:-1]:
        raise ValueError(
            f"root_pos (..., 3) and body_rot (..., 15, 3, 3) must share leading "
            f"dimensions, got {p.shape} and {r.shape}"
        )
    qpos = np.zeros((*p.shape[:-1], NQ))
    qpos[..., ROOT_POS] = p
    qpos[..., ROOT_QUAT] = matrix_to_quat(r[..., 0, :, :])
    for joint in JOINT_LAYOUT:
        child = r[..., joint.body_index, :, :]
        parent = r[..., PARENTS[joint.body_index], :, :]
        local = np.swapaxes(parent, -1, -2) @ child
        if joint.dofs == 3:
            qpos[..., joint.qpos] = matrix_to_euler_yxz(local)
        else:
            quat = matrix_to_quat(local)
            along = quat[..., 1:] @ np.asarray(joint.axes[0])
            angle = 2 * np.arctan2(along, quat[..., 0])
            qpos[..., joint.qpos_start] = wrap_angle(angle)
    return qpos


def action_to_joint_targets(action: np.ndarray) -> np.ndarray:
    """The paper's 28 actions to the 28 hinge targets the position actuators take.

    MAAIP §4.2: a 3-DoF joint's target is an exponential map, a 1-DoF joint's an
    angle. Each exponential map becomes the joint's y-x-z hinge angles; angles
    pass through.

    Args:
        action: (..., 28) actions in JOINT_LAYOUT order: a NumPy array, or a torch tensor (on
            any device), which gives a tensor there.

    Returns:
        (..., 28) hinge targets in radians (actuator order), before clipping to ctrlrange.
    """
    a = _check_last("action", action, (NUM_ACTUATED,))
    if is_torch_array(a):  # on Warp's device: the same columns, indexed by a tensor there
        columns = array_namespace(a).asarray(_EXPMAP_COLUMNS, device=device(a))
        targets = a.clone()
    else:
        columns, targets = _EXPMAP_COLUMNS, a.copy()
    # All 3-DoF joints in one call each: per joint, the calls' overhead dominated the step.
    targets[..., columns] = matrix_to_euler_yxz(expmap_to_matrix(a[..., columns]))
    return targets


_EXPMAP_COLUMNS = np.array(
    [range(j.action.start, j.action.stop) for j in JOINT_LAYOUT if j.dofs == 3]
)


def joint_targets_to_action(targets: np.ndarray) -> np.ndarray:
    """Inverse of `action_to_joint_targets`: hinge angles (..., 28) to actions (..., 28)."""
    t = _check_last("targets", targets, (NUM_ACTUATED,))
    action = t.copy()
    # All 3-DoF joints in one call each, as in `action_to_joint_targets` (scipy's Rotation has
    # a per-call cost; the spar's still boxer calls this every step).
    action[..., _EXPMAP_COLUMNS] = matrix_to_expmap(euler_yxz_to_matrix(t[..., _EXPMAP_COLUMNS]))
    return action
