"""DeepMimic motion clips, read and retargeted onto the boxer humanoid: the lift's synthetic
truth (`tasks.lift.synthetic`), the dataset's extra clips and training without footage use them.

DeepMimic's example clips (Peng et al., "DeepMimic", ACM TOG 37(4), 2018) come in the
pybullet==3.2.7 wheel, pulled by `ringside assets pull --dev` (the punch is a regular asset).

The same wheel's five walker clips (`WALKER_CLIPS`: a straight walk and four walks that
turn, by 30 and 56 degrees left and 99 and 53 degrees right, all 38 frames) are in the same
format, on the same humanoid: same joint layout, unit quaternions, knees negative and elbows
positive, turning left about +y towards -z.

The DeepMimic motion format, as checked against the four humanoid3d clips and the walker's:
- A JSON object {"Loop": "none" | "wrap", "Frames": [[...], ...]} (the run clip adds
  "RightJoints"/"LeftJoints" index lists, unused here).
- Each frame is 44 numbers: its duration dt in seconds (1/30 s; the last frame's is 0 in
  the humanoid3d clips and 1/30 in the walker's, and is not read),
  then 43 pose numbers: root position (3), root rotation (4), chest, neck, right hip (4
  each), right knee (1), right ankle, right shoulder (4 each), right elbow (1), left hip
  (4), left knee (1), left ankle, left shoulder (4 each), left elbow (1).
- Quaternions are (w, x, y, z): the first component is the large one (mean |w| 0.96-1.0
  for the joints). Root rotation is in the world, every other one relative to the parent
  body; at identity every body frame is aligned with the world, limbs hanging straight
  down, as in our humanoid.
- Not every quaternion is unit: punch's neck drops to norm 0.92 (frames 55-64), kick's
  right hip to 0.58 (frames 16-35) and its right ankle rises to 1.06 (frames 0-8). They
  are normalised here (`DeepMimicClip.renormalised` counts the frames).
- The world is y up, metres, with the character facing +x and its right side towards
  +z: the walk's root travels along +x at 0.85-0.87 m, and its right hip sits at +z.
- Knees and elbows are hinges about the body's z axis (pointing to the character's
  right): knee angles are all negative (flexion moves the shin back), elbows positive.

Shape letters: T frames.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import mujoco
import numpy as np
from scipy import sparse
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation, Slerp

from models.humanoid.boxer import JOINT_RANGES_DEG, BoneLengths, boxer_mjcf
from models.humanoid.compiled import humanoid_index
from models.humanoid.kinematics import (
    BODY_NAMES,
    HINGE_NAMES,
    JOINT_LAYOUT,
    NUM_BODIES,
    PARENTS,
    ROOT_POS,
    Y_UP_TO_Z_UP,
    axis_angle_matrix,
    body_rotations,
    euler_yxz_to_matrix,
    matrix_to_euler_yxz,
    matrix_to_quat,
    qpos_from_body_rotations,
    quat_to_matrix,
    wrap_angle,
)
from tasks.errors import BadInput

# The clips, by short name, and where `storage.assets` puts them under the assets folder.
CLIPS: tuple[str, ...] = ("punch", "kick", "walk", "run")
MOTIONS_DIR = "dev/motions"
# The walker's clips (pybullet_data/data/motions/walker), by short name -> file name; put
# under MOTIONS_DIR/walker. Not in CLIPS, whose order seeds `tasks.lift.synthetic`.
WALKER_FILES: Mapping[str, str] = MappingProxyType(
    {
        "walker_forward": "0walk_forward.txt",
        "walker_turn_left0": "turn_left0.txt",
        "walker_turn_left1": "turn_left1.txt",
        "walker_turn_right0": "turn_right0.txt",
        "walker_turn_right1": "turn_right1.txt",
    }
)
WALKER_CLIPS: tuple[str, ...] = tuple(WALKER_FILES)

FPS = 30.0

# One DeepMimic frame after its duration: (field, width), in order.
FRAME_LAYOUT: tuple[tuple[str, int], ...] = (
    ("root_pos", 3),
    ("root_quat", 4),
    ("chest", 4),
    ("neck", 4),
    ("right_hip", 4),
    ("right_knee", 1),
    ("right_ankle", 4),
    ("right_shoulder", 4),
    ("right_elbow", 1),
    ("left_hip", 4),
    ("left_knee", 1),
    ("left_ankle", 4),
    ("left_shoulder", 4),
    ("left_elbow", 1),
)
FRAME_WIDTH = 1 + sum(width for _, width in FRAME_LAYOUT)  # 44 with the duration

# DeepMimic joint -> (its parent DeepMimic joint, our body it drives). Our hands are welded
# to the forearms, as DeepMimic's wrists are.
_DM_BODIES: Mapping[str, tuple[str | None, tuple[str, ...]]] = MappingProxyType(
    {
        "root": (None, ("pelvis",)),
        "chest": ("root", ("torso",)),
        "neck": ("chest", ("head",)),
        "right_shoulder": ("chest", ("right_upper_arm",)),
        "right_elbow": ("right_shoulder", ("right_lower_arm", "right_hand")),
        "left_shoulder": ("chest", ("left_upper_arm",)),
        "left_elbow": ("left_shoulder", ("left_lower_arm", "left_hand")),
        "right_hip": ("root", ("right_thigh",)),
        "right_knee": ("right_hip", ("right_shin",)),
        "right_ankle": ("right_knee", ("right_foot",)),
        "left_hip": ("root", ("left_thigh",)),
        "left_knee": ("left_hip", ("left_shin",)),
        "left_ankle": ("left_knee", ("left_foot",)),
    }
)

# DeepMimic humanoid's thigh (hip to knee) and shin (knee to ankle) in metres, from its
# character file; root paths are scaled by our leg over this one so strides fit our legs.
DEEPMIMIC_LEG = 0.421546 + 0.40987

# The unit quaternion tolerance past which a clip's quaternion counts as renormalised.
_UNIT_TOLERANCE = 1e-3


@dataclass(frozen=True, eq=False)
class DeepMimicClip:
    """One DeepMimic motion clip as stored, in its own y-up world.

    Attributes:
        path: the file it was read from.
        loop: its "Loop" entry ("none" or "wrap").
        frames: (T, 44) the raw numbers, duration first.
        dt: (T,) each frame's duration in seconds (the last is 0).
        root_pos: (T, 3) root (pelvis, mid-hip) position, metres, y up.
        root_quat: (T, 4) root rotation in the world, unit (w, x, y, z).
        joint_quats: 3-DoF joint name -> (T, 4) unit rotation relative to the parent.
        joint_angles: 1-DoF joint name (knees, elbows) -> (T,) angle in radians about the
            body's z axis.
        renormalised: quaternion name -> how many frames were more than 1e-3 off unit
            length before normalising (only names with at least one).
    """

    path: Path
    loop: str
    frames: np.ndarray
    dt: np.ndarray
    root_pos: np.ndarray
    root_quat: np.ndarray
    joint_quats: Mapping[str, np.ndarray]
    joint_angles: Mapping[str, np.ndarray]
    renormalised: Mapping[str, int]

    @property
    def num_frames(self) -> int:
        return len(self.frames)

    @property
    def times(self) -> np.ndarray:
        """(T,) each frame's start time in seconds, from 0."""
        return np.concatenate([[0.0], np.cumsum(self.dt[:-1])])

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the last."""
        return float(self.times[-1])


def _frozen(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array


def load_deepmimic(path: str | Path) -> DeepMimicClip:
    """Read a DeepMimic motion file (format in the module docstring).

    Raises:
        BadInput: naming the file, if it is unreadable, not JSON, has no "Frames" of 44
            finite numbers each, a frame duration that is not positive (but the last), or a
            quaternion with norm below 0.1.
    """
    path = Path(path)
    try:
        document = json.loads(path.read_text())
    except OSError as error:
        raise BadInput(str(path), f"cannot be read ({error.strerror or error})") from None
    except json.JSONDecodeError as error:
        raise BadInput(str(path), f"is not a JSON DeepMimic motion ({error})") from None
    if not isinstance(document, dict) or not isinstance(document.get("Frames"), list):
        raise BadInput(str(path), 'is not a DeepMimic motion: no "Frames" list')
    try:
        frames = np.array(document["Frames"], dtype=np.float64)
    except (TypeError, ValueError):
        raise BadInput(str(path), '"Frames" must be rows of numbers of equal length') from None
    if frames.ndim != 2 or frames.shape[1] != FRAME_WIDTH or len(frames) < 2:
        raise BadInput(
            str(path),
            f'"Frames" must be at least 2 rows of {FRAME_WIDTH} numbers '
            f"(dt, then {FRAME_WIDTH - 1} pose numbers), got shape {frames.shape}",
        )
    if not np.isfinite(frames).all():
        bad = int(np.argwhere(~np.isfinite(frames))[0, 0])
        raise BadInput(str(path), f"frame {bad} holds a non-finite number")
    dt = frames[:, 0].copy()
    if np.any(dt[:-1] <= 0):
        bad = int(np.argmax(dt[:-1] <= 0))
        raise BadInput(str(path), f"frame {bad} has duration {dt[bad]}; it must be positive")

    fields: dict[str, np.ndarray] = {}
    start = 1
    for name, width in FRAME_LAYOUT:
        fields[name] = frames[:, start : start + width].copy()
        start += width
    renormalised: dict[str, int] = {}
    quats: dict[str, np.ndarray] = {}
    for name, width in FRAME_LAYOUT:
        if width != 4:
            continue
        q = fields[name]
        norm = np.linalg.norm(q, axis=1)
        if norm.min() < 0.1:
            bad = int(np.argmin(norm))
            raise BadInput(str(path), f"frame {bad}: {name} quaternion has norm {norm[bad]:.3g}")
        off = int(np.sum(np.abs(norm - 1.0) > _UNIT_TOLERANCE))
        if off:
            renormalised[name] = off
        quats[name] = _frozen(q / norm[:, None])
    return DeepMimicClip(
        path=path,
        loop=str(document.get("Loop", "none")),
        frames=_frozen(frames),
        dt=_frozen(dt),
        root_pos=_frozen(fields["root_pos"]),
        root_quat=quats.pop("root_quat"),
        joint_quats=MappingProxyType(quats),
        joint_angles=MappingProxyType(
            {name: _frozen(fields[name][:, 0]) for name, width in FRAME_LAYOUT if width == 1}
        ),
        renormalised=MappingProxyType(renormalised),
    )


def clip_path(assets: str | Path, clip_name: str) -> Path:
    """Where `storage.assets` puts clip `clip_name` (one of CLIPS or WALKER_CLIPS) under the
    assets folder."""
    if clip_name in WALKER_FILES:
        return Path(assets) / MOTIONS_DIR / "walker" / WALKER_FILES[clip_name]
    if clip_name not in CLIPS:
        raise ValueError(f"clip_name must be one of {CLIPS + WALKER_CLIPS}, got {clip_name!r}")
    return Path(assets) / MOTIONS_DIR / f"humanoid3d_{clip_name}.txt"


# --------------------------------------------------------------------------
# Retargeting
# --------------------------------------------------------------------------


def _resample(clip: DeepMimicClip, fps: float) -> dict[str, np.ndarray]:
    """The clip's fields at times k / fps (linear for positions and angles, slerp for rotations)."""
    times = clip.times
    # 1 ms of slack keeps the last frame when the durations round below 1/fps (walk: 0.033332).
    count = int(math.floor(clip.duration * fps + 1e-3 * fps)) + 1
    query = np.minimum(np.arange(count) / fps, times[-1])
    i = np.clip(np.searchsorted(times, query, side="right") - 1, 0, len(times) - 2)
    u = np.clip((query - times[i]) / (times[i + 1] - times[i]), 0.0, 1.0)
    out = {"root_pos": clip.root_pos[i] * (1 - u[:, None]) + clip.root_pos[i + 1] * u[:, None]}

    def slerp(quats: np.ndarray) -> np.ndarray:  # (T, 4) w-x-y-z keyframes at `times`
        keys = Rotation.from_quat(quats, scalar_first=True)
        return Slerp(times, keys)(query).as_quat(scalar_first=True)

    out["root"] = slerp(clip.root_quat)
    for name, q in clip.joint_quats.items():
        out[name] = slerp(q)
    for name, a in clip.joint_angles.items():
        out[name] = a[i] * (1 - u) + a[i + 1] * u
    return out


def foot_box_corners(model: mujoco.MjModel, qpos: np.ndarray, *, prefix: str = "") -> np.ndarray:
    """World positions of the corners of the humanoid's two foot boxes (its floor contacts).

    Args:
        model: a compiled model holding the boxer named by `prefix`.
        qpos: (T, nq) model configurations.

    Returns:
        (T, 2, 8, 3) corners of the left then right foot geom, metres.
    """
    q = np.asarray(qpos, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != model.nq:
        raise ValueError(f"qpos must have shape (T, {model.nq}), got {q.shape}")
    humanoid_index(model, prefix=prefix)  # checks the layout, names the missing element
    ids = [
        mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"{prefix}{s}_foot")
        for s in ("left", "right")
    ]
    if min(ids) < 0:
        raise ValueError(f"model has no foot geoms {prefix}left_foot / {prefix}right_foot")
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    local = signs[None] * model.geom_size[ids][:, None, :]  # (2, 8, 3) in each geom's frame
    data = mujoco.MjData(model)
    out = np.empty((len(q), 2, 8, 3))
    for t, frame in enumerate(q):
        data.qpos[:] = frame
        mujoco.mj_kinematics(model, data)
        rot = data.geom_xmat[ids].reshape(2, 3, 3)
        out[t] = np.einsum("fij,fkj->fki", rot, local) + data.geom_xpos[ids][:, None, :]
    return out


def _clip_circular(angle: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Angles outside [lo, hi] moved to the limit nearest round the circle.

    A hinge angle is periodic: a shoulder at +170 deg against a (-180, 60) range is 10 deg
    from -180, not 110 from 60, and clipping to 60 would swing the arm to the other side.
    """
    inside = (angle >= lo) & (angle <= hi)
    to_lo = np.abs(wrap_angle(angle - lo))
    to_hi = np.abs(wrap_angle(angle - hi))
    return np.where(inside, angle, np.where(to_lo < to_hi, lo, hi))


def _geodesic_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in degrees of the rotation between (..., 3, 3) rotations a and b."""
    between = Rotation.from_matrix(np.swapaxes(a, -1, -2) @ b, assume_valid=True)
    return np.degrees(between.magnitude())


# Fitting a 3-DoF joint's run of frames outside its limits (`_fit_run`); the figures are
# from the punch's right shoulder, the one joint they decide (see `retarget`).
# The body's z axis (along the bone for the limbs, the spine for torso and head, the sole's
# normal for the feet) weighs this much more than its x and y axes: a limb's direction,
# which places the joint below it, is kept before its twist about itself. With equal
# weights the nearest rotation turns the punch's raised upper arm up to 24 deg off its
# direction to save twist, and the wrist lands 12-18 cm off rather than 2-4 (frames 29-44).
_BONE_WEIGHT = 10.0
# No hinge steps more in a frame than this, or than its body is asked to turn in that frame
# if more; each radian beyond weighs _OVERSTEP_WEIGHT times a radian of rotation error.
# Steps within the limit cost nothing.
_STEP_LIMIT_DEG = 30.0
_OVERSTEP_WEIGHT = 10.0


def _hat(v: np.ndarray) -> np.ndarray:
    """(..., 3) vectors -> (..., 3, 3) cross-product matrices."""
    x, y, z = np.moveaxis(v, -1, 0)
    zero = np.zeros_like(x)
    return np.stack(
        [np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)],
        -2,
    )


def _yxz_with_axes(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R = Ry(a) Rx(b) Rz(c) and the axes u_k with dR/d(angle k) = hat(u_k) R.

    Args:
        angles: (n, 3) hinge angles (a, b, c).

    Returns:
        (n, 3, 3) rotations and (n, 3, 3) axes, one row per angle: y, Ry(a) x, R z.
    """
    rotation = euler_yxz_to_matrix(angles)
    a = angles[:, 0]
    axes = np.zeros((len(angles), 3, 3))
    axes[:, 0, 1] = 1.0
    axes[:, 1, 0], axes[:, 1, 2] = np.cos(a), -np.sin(a)
    axes[:, 2] = rotation[:, :, 2]
    return rotation, axes


_AXIS_WEIGHTS = np.sqrt(0.5) * np.array([1.0, 1.0, _BONE_WEIGHT])  # on R's columns


def _misfit(rotation: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """(..., 3, 3) residual of a rotation against the wanted one, its body axes weighted by
    `_AXIS_WEIGHTS`; with equal weights its squared norm is |R - W|_F^2 / 2 = 2 - 2 cos(theta),
    theta^2 to 4th order."""
    return (rotation - wanted) * _AXIS_WEIGHTS


def _overstep(step: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """How far each hinge step goes past its limit, signed; 0 within it."""
    return np.sign(step) * np.maximum(np.abs(step) - limit, 0.0)


def _fit_run(
    local: np.ndarray,
    start: np.ndarray,
    before: np.ndarray | None,
    after: np.ndarray | None,
    limit: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
) -> np.ndarray:
    """y-x-z angles within [lo, hi] for a run of n frames, by bounded least squares (scipy's
    trf): each frame's `_misfit` to its wanted rotation, and how far each hinge step (from
    `before` and to `after`, the fixed frames either side, where not None) goes past its
    limit, by `_OVERSTEP_WEIGHT`.

    Args:
        local: (n, 3, 3) wanted local rotations.
        start: (n, 3) first guess within [lo, hi].
        limit: (m,) each step's limit in radians, m = n - 1 + the fixed frames given.

    Returns:
        (n, 3) angles in radians.
    """
    n = len(local)
    first = -1 if before is not None else 0
    last = n if after is not None else n - 1
    m = last - first  # steps (first, first + 1) ... (last - 1, last)
    # steps = D @ angles + fixed, row k for step k's three hinges
    rows, cols, signs = [], [], []
    for k in range(m):
        for frame, sign in ((first + k + 1, 1.0), (first + k, -1.0)):
            if 0 <= frame < n:
                rows.append(3 * k + np.arange(3))
                cols.append(3 * frame + np.arange(3))
                signs.append(np.full(3, sign))
    steps_of = sparse.csr_array(
        (np.concatenate(signs), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * m, 3 * n)
    )
    fixed = np.zeros((m, 3))
    if before is not None:
        fixed[0] -= before
    if after is not None:
        fixed[-1] += after
    fixed = fixed.ravel()
    row_limit = np.repeat(limit, 3)
    rot_rows = np.arange(9 * n).reshape(n, 9, 1).repeat(3, 2).ravel()
    rot_cols = np.arange(3 * n).reshape(n, 1, 3).repeat(9, 1).ravel()

    def residual(v: np.ndarray) -> np.ndarray:
        misfit = _misfit(euler_yxz_to_matrix(v.reshape(n, 3)), local)
        over = _overstep(steps_of @ v + fixed, row_limit)
        return np.concatenate([misfit.ravel(), _OVERSTEP_WEIGHT * over])

    def jacobian(v: np.ndarray) -> sparse.csr_array:
        rotation, axes = _yxz_with_axes(v.reshape(n, 3))
        d = _misfit(_hat(axes) @ rotation[:, None], 0.0)  # (n, 3 angles, 3, 3)
        rot = sparse.csr_array(
            (d.reshape(n, 3, 9).transpose(0, 2, 1).ravel(), (rot_rows, rot_cols)),
            shape=(9 * n, 3 * n),
        )
        past = np.abs(steps_of @ v + fixed) > row_limit
        over = sparse.diags_array(_OVERSTEP_WEIGHT * past.astype(float)) @ steps_of
        return sparse.vstack([rot, over], format="csr")

    fit = least_squares(
        residual,
        np.clip(start, lo, hi).ravel(),
        jac=jacobian,
        bounds=(np.tile(lo, n), np.tile(hi, n)),
        # LSMR rather than the exact solver's dense SVD, which a busy machine's threaded
        # BLAS slows many-fold (same answers; 40 ms against 0.3-2 s on the punch). dogbox
        # stops early with the arm past the gimbal lock (tests/test_deepmimic.py).
        method="trf",
        tr_solver="lsmr",
    )
    return fit.x.reshape(n, 3)


def _nearest_branches(local: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The first guess for `_fit_run`: per frame whichever of the two Euler solutions of the
    wanted rotation, (a, b, c) or (a + pi, pi - b, c + pi), clipped round the circle to
    [lo, hi], has the smaller `_misfit`."""
    a, b, c = np.moveaxis(matrix_to_euler_yxz(local), -1, 0)
    branches = np.stack([np.stack([a, b, c], -1), np.stack([a + np.pi, np.pi - b, c + np.pi], -1)])
    options = _clip_circular(wrap_angle(branches), lo, hi)  # (2, n, 3)
    misfit = np.sum(_misfit(euler_yxz_to_matrix(options), local) ** 2, axis=(-2, -1))
    return options[np.argmin(misfit, axis=0), np.arange(len(local))]


def _euler_within_limits(local: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """A 3-DoF joint's y-x-z hinge angles within [lo, hi] for (T, 3, 3) wanted local
    rotations, continuous over time.

    Frames whose exact angles (`matrix_to_euler_yxz`) lie inside the limits keep them. Each
    run of frames outside is fitted as a whole (`_fit_run`) between the exact frames either
    side. Frame by frame the nearest rotation within limits is not continuous: where the
    wanted rotation passes beside the gimbal lock (x near -90 deg), a small turn of the body
    moves the Euler angles by up to 180 deg (the punch's right shoulder jumped 148-240 deg in
    a frame), and which solution's clipped angles are nearer flips from frame to frame.

    Returns:
        (T, 3) angles in radians.
    """
    exact = matrix_to_euler_yxz(local)
    outside = ~np.all((exact >= lo) & (exact <= hi), axis=-1)
    angles = exact.copy()
    if not outside.any():
        return angles
    turn = Rotation.from_matrix(np.swapaxes(local[:-1], -1, -2) @ local[1:]).magnitude()
    step_limit = np.maximum(turn, math.radians(_STEP_LIMIT_DEG))  # (T - 1,) step t -> t + 1
    edges = np.diff(np.concatenate([[0], outside.astype(int), [0]]))
    for first, stop in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
        before = exact[first - 1] if first > 0 else None
        after = exact[stop] if stop < len(exact) else None
        limit = step_limit[max(first - 1, 0) : min(stop, len(exact) - 1)]
        start = _nearest_branches(local[first:stop], lo, hi)
        angles[first:stop] = _fit_run(local[first:stop], start, before, after, limit, lo, hi)
    return angles


def _limited_qpos(root_pos: np.ndarray, body_rot: np.ndarray) -> np.ndarray:
    """`qpos_from_body_rotations` with every hinge inside `JOINT_RANGES_DEG`.

    Joints are fitted from the root outwards, each to its body's wanted world rotation as
    seen from its parent's achieved one, so a shoulder held inside its limits passes its
    error on to the elbow, which takes up what it can. A 3-DoF joint's angles come from
    `_euler_within_limits` (continuous over time); a knee or elbow takes the twist about its
    hinge axis (the nearest rotation it can make), clipped round the circle.
    """
    qpos = qpos_from_body_rotations(root_pos, body_rot)  # root pose, and the unlimited angles
    achieved = body_rot.copy()
    for joint in JOINT_LAYOUT:
        lo, hi = np.radians(np.array([JOINT_RANGES_DEG[h] for h in joint.hinges])).T
        parent = achieved[:, PARENTS[joint.body_index]]
        local = np.swapaxes(parent, -1, -2) @ body_rot[:, joint.body_index]
        if joint.dofs == 3:
            angles = _euler_within_limits(local, lo, hi)
            rotation = euler_yxz_to_matrix(angles)
        else:
            quat = matrix_to_quat(local)
            axis = np.asarray(joint.axes[0])
            twist = wrap_angle(2 * np.arctan2(quat[:, 1:] @ axis, quat[:, 0]))  # nearest about axis
            angles = _clip_circular(twist, lo, hi)[:, None]
            rotation = axis_angle_matrix(axis, angles[:, 0])
        qpos[:, joint.qpos] = angles
        achieved[:, joint.body_index] = parent @ rotation
        for child, body_parent in enumerate(PARENTS):
            if body_parent == joint.body_index and BODY_NAMES[child].endswith("_hand"):
                achieved[:, child] = achieved[:, joint.body_index]  # welded
    return qpos


@dataclass(frozen=True, eq=False)
class Retargeted:
    """A DeepMimic clip on our humanoid.

    Attributes:
        qpos: (T, 35) humanoid qpos at `fps`, z up, lowest foot corner of the clip at z = 0.
        fps: frames per second.
        scale: factor applied to the clip's root path (our leg length over DeepMimic's).
        clipped: hinge name -> fraction of frames in which the clip's exact angle lay
            outside our joint limits (only hinges with at least one).
        rotation_error_deg: body name -> the largest angle (over frames) between the
            clip's world rotation of the body and the humanoid's within its limits (only
            bodies off by more than 0.1 deg).
        rotation_error_mean_deg: the same bodies -> that angle's mean over frames.
    """

    qpos: np.ndarray
    fps: float
    scale: float
    clipped: Mapping[str, float]
    rotation_error_deg: Mapping[str, float]
    rotation_error_mean_deg: Mapping[str, float]


def _wanted_pose(clip: DeepMimicClip, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """The clip at `fps` in our z-up axes, before joint limits and scaling.

    Returns:
        (T, 3) root path in the clip's metres and (T, 15, 3, 3) world rotations of our
        bodies (BODY_NAMES order).
    """
    fields = _resample(clip, fps)
    c = Y_UP_TO_Z_UP
    # Each DeepMimic joint's local rotation, expressed in our axes (C L C^T). The same
    # rest pose on both sides means the conjugated rotations are our bodies' rotations.
    local: dict[str, np.ndarray] = {}
    for name in _DM_BODIES:
        if name in clip.joint_angles:
            rotation = axis_angle_matrix((0.0, 0.0, 1.0), fields[name])
        else:
            rotation = quat_to_matrix(fields[name])
        local[name] = c @ rotation @ c.T
    world: dict[str, np.ndarray] = {}
    body_rot = np.empty((len(fields["root"]), NUM_BODIES, 3, 3))
    for name, (parent, bodies) in _DM_BODIES.items():  # parents come first
        world[name] = local[name] if parent is None else world[parent] @ local[name]
        for body in bodies:
            body_rot[:, BODY_NAMES.index(body)] = world[name]
    return fields["root_pos"] @ c.T, body_rot


def retarget_report(
    clip: DeepMimicClip,
    bones: BoneLengths = BoneLengths(),  # noqa: B008 (frozen, so a safe default)
    *,
    fps: float = FPS,
) -> Retargeted:
    """Retarget `clip` to our humanoid with `bones`; see `retarget`. Also says what the joint
    limits changed."""
    if not isinstance(clip, DeepMimicClip):
        raise TypeError(f"clip must be a DeepMimicClip, got {type(clip).__name__}")
    if not isinstance(bones, BoneLengths):
        raise TypeError(f"bones must be a BoneLengths, got {type(bones).__name__}")
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive frame rate, got {fps!r}")
    path, body_rot = _wanted_pose(clip, fps)
    scale = (bones.thigh + bones.shin) / DEEPMIMIC_LEG
    root_pos = path * scale
    exact = qpos_from_body_rotations(root_pos, body_rot)[:, 7:]
    limits = np.radians(np.array([JOINT_RANGES_DEG[h] for h in HINGE_NAMES]))
    outside = (exact < limits[:, 0] - 1e-9) | (exact > limits[:, 1] + 1e-9)
    clipped = {
        h: float(outside[:, k].mean()) for k, h in enumerate(HINGE_NAMES) if outside[:, k].any()
    }
    qpos = _limited_qpos(root_pos, body_rot)
    error = _geodesic_deg(body_rotations(qpos), body_rot)  # (T, bodies)
    worst, mean = error.max(axis=0), error.mean(axis=0)
    off = [k for k, e in enumerate(worst) if e > 0.1]
    rotation_error = {BODY_NAMES[k]: float(worst[k]) for k in off}

    # Put the lowest foot point of the whole clip on the floor: one shift, so the root's
    # vertical motion (a crouch, a jump) is kept.
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(bones))
    lowest = foot_box_corners(model, qpos)[..., 2].min()
    qpos[:, ROOT_POS.start + 2] -= lowest
    return Retargeted(
        qpos=qpos,
        fps=float(fps),
        scale=float(scale),
        clipped=MappingProxyType(clipped),
        rotation_error_deg=MappingProxyType(rotation_error),
        rotation_error_mean_deg=MappingProxyType({BODY_NAMES[k]: float(mean[k]) for k in off}),
    )


def retarget(
    clip: DeepMimicClip,
    bones: BoneLengths = BoneLengths(),  # noqa: B008 (frozen, so a safe default)
    *,
    fps: float = FPS,
) -> np.ndarray:
    """A DeepMimic clip as our humanoid's qpos, in our z-up world.

    Steps: resample to `fps` (slerp); turn y up into z up (`Y_UP_TO_Z_UP`); map DeepMimic's
    root, chest, neck, hips, knees, ankles, shoulders and elbows onto our pelvis, abdomen,
    neck, hips, knees, ankles, shoulders and elbows through world body rotations and
    `qpos_from_body_rotations` (3-DoF joints to y-x-z hinge angles, knees and elbows to
    their hinge's angle); keep every hinge within `JOINT_RANGES_DEG`; scale the root path by
    our leg length over DeepMimic's (so a stride still spans the feet: the walk's feet
    skate least at that scale, 0.013 cm/frame by eq. 6.7 against 0.05 unscaled); and lift
    the whole clip so that its lowest foot-box corner touches z = 0.

    How often the limits bite (default bones; fraction of frames per hinge, from
    `retarget_report`): walk never; run 20 % (shoulder_y: the arms swing back 10 deg past
    60) and 8 % (ankle_y, 5 deg); kick 28 % right_ankle_y, 15 % right_hip_z, 6 % left_hip_y
    and a few % neck_x, left_ankle_x, left_hip_z, no body more than 11 deg off; punch 37 %
    right_shoulder_y and _z and 25 % neck_z. The punch's right arm is the one large change:
    raised sideways behind the shoulder line (frames 25-49), its upper-arm twist exceeds 90
    deg by up to 76 (the upper arm 13 deg off on average over the clip, 48 at most), and the
    arm passes 6 deg from the shoulder's gimbal lock on the way in and out, where following
    it would swing the shoulder's y hinge by 148 deg in a frame on the way in and 214 on the
    way out. Spread over 5 and 6 frames (no hinge steps more than 41 deg a frame), the swings
    leave the wrist up to 22 cm from where the unlimited pose puts it (frames 25-27; 8 of 65
    frames over 5 cm, 2-4 cm in frames 29-44). Limits are enforced joint by joint from the
    root out (`_limited_qpos`; 3-DoF joints by `_euler_within_limits`, continuous over
    time), so a capped shoulder's error is taken up by the elbow where it can be.

    Args:
        clip: from `load_deepmimic`.
        bones: the humanoid's segment lengths.
        fps: output frame rate.

    Returns:
        (T, 35) qpos, T = floor(duration * fps) + 1.
    """
    return retarget_report(clip, bones, fps=fps).qpos
