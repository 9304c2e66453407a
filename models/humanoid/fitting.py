"""Step 2 of the lift: the boxer humanoid fitted to 3D joints by inverse kinematics.

`Skeleton` is the humanoid's forward kinematics and geometric site Jacobian in NumPy, batched
over frames, with its constants read from a compiled MuJoCo model (so its FK equals MuJoCo's).
`fit_humanoid` makes an analytic first guess of each body's rotation from the joints
(`body_rotations_from_points`), then runs damped least squares (Levenberg-Marquardt,
`solve_ik`) batched over all frames, joint limits kept by clamping the step (an active set).

Shape letters: T frames, S humanoid sites, D = 34 degrees of freedom. Units: metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.compiled import humanoid_index
from models.humanoid.kinematics import (
    BLAZEPOSE_TO_SITE,
    BODY_NAMES,
    JOINT_LAYOUT,
    NUM_ACTUATED,
    NUM_BODIES,
    ROOT_POS,
    ROOT_QUAT,
    SITE_NAMES,
    axis_angle_matrix,
    matrix_to_quat,
    qpos_from_body_rotations,
    quat_to_matrix,
)
from models.pose.types import BLAZEPOSE_33

# Humanoid sites on the head: their IK weight is `fit_humanoid`'s face_weight.
_FACE_SITES = frozenset(
    ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "mouth_left", "mouth_right")
)


# ---------------------------------------------------------------------------------------------
# Humanoid kinematics in NumPy: FK and the geometric site Jacobian, batched over frames


@dataclass(frozen=True, eq=False)
class Skeleton:
    """Forward kinematics and site Jacobians of one boxer of a compiled MuJoCo model.

    The constants come from the model (body offsets, hinge axes, site offsets, ranges), so
    FK here equals MuJoCo's (tested). A pose is (root position (T, 3), root rotation
    (T, 3, 3), 28 hinge angles (T, 28)); a step is D = 34 numbers: root translation (3),
    root rotation vector in the world frame (3), hinge angles (28).

    Attributes:
        parents: (15,) parent of each body (index into BODY_NAMES; -1 for the pelvis).
        offsets: (15, 3) body origin in its parent's frame.
        rest: (15, 3, 3) body rotation in its parent's frame at qpos0 (identity for the boxer).
        hinge_body: (28,) body each hinge moves.
        hinge_axis: (28, 3) hinge axes in their body's frame.
        ranges: (28, 2) hinge limits, radians.
        site_body: (S,) body of each site (SITE_NAMES order).
        site_offset: (S, 3) site positions in their body's frame.
        moves: (S, 28) bool, hinge k moves site s.
    """

    parents: np.ndarray
    offsets: np.ndarray
    rest: np.ndarray
    hinge_body: np.ndarray
    hinge_axis: np.ndarray
    ranges: np.ndarray
    site_body: np.ndarray
    site_offset: np.ndarray
    moves: np.ndarray

    @classmethod
    def from_model(cls, model: mujoco.MjModel, *, prefix: str = "") -> Skeleton:
        """Read the boxer named by `prefix` out of `model`."""
        index = humanoid_index(model, prefix=prefix)
        local = {int(b): i for i, b in enumerate(index.body_ids)}
        parents = np.array([local.get(int(model.body_parentid[b]), -1) for b in index.body_ids])
        offsets = model.body_pos[index.body_ids].copy()
        rest = quat_to_matrix(model.body_quat[index.body_ids])
        hinge_body, hinge_axis, ranges = [], [], []
        for joint in JOINT_LAYOUT:
            for hinge in joint.hinges:
                j = model.joint(prefix + hinge)
                if np.any(j.pos != 0):
                    raise ValueError(f"model joint {prefix + hinge!r} must sit at its body origin")
                hinge_body.append(local[int(j.bodyid[0])])
                hinge_axis.append(j.axis.copy())
                ranges.append(j.range.copy())
        site_body = np.array([local[int(model.site_bodyid[s])] for s in index.site_ids])
        ancestors = np.zeros((NUM_BODIES, NUM_BODIES), dtype=bool)  # [b, a]: a is b or above
        for b in range(NUM_BODIES):
            a = b
            while a >= 0:
                ancestors[b, a] = True
                a = parents[a]
        hinge_body = np.array(hinge_body)
        return cls(
            parents=parents,
            offsets=offsets,
            rest=rest,
            hinge_body=hinge_body,
            hinge_axis=np.array(hinge_axis),
            ranges=np.array(ranges),
            site_body=site_body,
            site_offset=model.site_pos[index.site_ids].copy(),
            moves=ancestors[site_body][:, hinge_body],
        )

    def forward(
        self, root_pos: np.ndarray, root_rot: np.ndarray, hinges: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Forward kinematics.

        Args:
            root_pos: (T, 3), root_rot: (T, 3, 3), hinges: (T, 28).

        Returns:
            body positions (T, 15, 3), body rotations (T, 15, 3, 3), hinge axes in the world
            (T, 28, 3), site positions (T, S, 3).
        """
        frames = len(root_pos)
        pos = np.empty((frames, NUM_BODIES, 3))
        rot = np.empty((frames, NUM_BODIES, 3, 3))
        axes = np.empty((frames, NUM_ACTUATED, 3))
        pos[:, 0] = root_pos
        rot[:, 0] = root_rot @ self.rest[0]
        for b in range(1, NUM_BODIES):
            p = self.parents[b]
            pos[:, b] = pos[:, p] + rot[:, p] @ self.offsets[b]
            r = rot[:, p] @ self.rest[b]
            for k in np.flatnonzero(self.hinge_body == b):
                axes[:, k] = r @ self.hinge_axis[k]
                r = r @ axis_angle_matrix(self.hinge_axis[k], hinges[:, k])
            rot[:, b] = r
        sites = pos[:, self.site_body] + np.einsum(
            "tsij,sj->tsi", rot[:, self.site_body], self.site_offset
        )
        return pos, rot, axes, sites

    def jacobian(
        self,
        root_pos: np.ndarray,
        body_pos: np.ndarray,
        axes: np.ndarray,
        sites: np.ndarray,
        site_index: np.ndarray,
    ) -> np.ndarray:
        """Geometric Jacobian of site positions with respect to the D = 34 step coordinates.

        d p_s / d root translation = I; d p_s / d root rotation vector w = -[p_s - root]_x;
        d p_s / d hinge k = a_k x (p_s - o_k) when hinge k moves site s (a_k its world axis,
        o_k its body's origin), else 0.

        Args:
            root_pos: (T, 3); body_pos: (T, 15, 3); axes: (T, 28, 3) from `forward`.
            sites: (T, S', 3) positions of the sites `site_index` (S',) picks.

        Returns:
            (T, S', 3, 34).
        """
        frames, count = sites.shape[:2]
        jac = np.zeros((frames, count, 3, 6 + NUM_ACTUATED))
        jac[..., :3] = np.eye(3)
        d = sites - root_pos[:, None]
        zero = np.zeros(d.shape[:-1])
        jac[..., 3:6] = -np.stack(
            [
                np.stack([zero, -d[..., 2], d[..., 1]], -1),
                np.stack([d[..., 2], zero, -d[..., 0]], -1),
                np.stack([-d[..., 1], d[..., 0], zero], -1),
            ],
            axis=-2,
        )
        anchors = body_pos[:, self.hinge_body]  # (T, 28, 3)
        lever = sites[:, :, None, :] - anchors[:, None, :, :]  # (T, S', 28, 3)
        columns = np.cross(axes[:, None], lever) * self.moves[site_index][None, :, :, None]
        jac[..., 6:] = np.swapaxes(columns, -1, -2)
        return jac


def qpos_to_pose(qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(T, 35) qpos to (root position (T, 3), root rotation (T, 3, 3), hinges (T, 28))."""
    return qpos[:, ROOT_POS].copy(), quat_to_matrix(qpos[:, ROOT_QUAT]), qpos[:, 7:].copy()


def pose_to_qpos(root_pos: np.ndarray, root_rot: np.ndarray, hinges: np.ndarray) -> np.ndarray:
    """Inverse of `qpos_to_pose`: (T, 35) qpos."""
    return np.concatenate([root_pos, matrix_to_quat(root_rot), hinges], axis=1)


def wrap_to_ranges(hinges: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """Hinge angles moved by a whole turn where that brings them nearer their range, then
    clipped into it.

    Args:
        hinges: (T, 28) radians.
        ranges: (28, 2) limits (radians).

    Returns:
        (T, 28) angles within `ranges`.
    """
    lo, hi = ranges[:, 0], ranges[:, 1]
    candidates = hinges[..., None] + np.array([-2 * np.pi, 0.0, 2 * np.pi])
    outside = np.maximum(lo[:, None] - candidates, 0) + np.maximum(candidates - hi[:, None], 0)
    best = np.take_along_axis(candidates, outside.argmin(-1)[..., None], -1)[..., 0]
    return np.clip(best, lo, hi)


def _rotation_step(root_rot: np.ndarray, rotvec: np.ndarray) -> np.ndarray:
    """exp([w]_x) @ root_rot for (T, 3) rotation vectors w in the world frame, orthonormal:
    composed as quaternions (`Rotation.from_matrix` takes the rotation nearest root_rot)."""
    return (Rotation.from_rotvec(rotvec) * Rotation.from_matrix(root_rot)).as_matrix()


# Our own Levenberg-Marquardt rather than scipy.optimize.least_squares, measured on the lift's
# synthetic DeepMimic cases with the same start, residual and Jacobian (benchmarks/ik_solvers.py,
# 528 frames, 2026-11-27): 'trf' with the hinge ranges as bounds, frame by frame, ends 0.07 mm
# closer (6.70 against 6.77 mm mean site error) at 7.3x the CPU time (11.8 against 1.6 ms a
# frame); 'lm' takes no bounds and leaves 44 % of frames with a hinge out of its range; 'trf'
# as one problem over all frames shares one trust region, so it needs many more steps than a
# frame-wise solve.
def solve_ik(
    skeleton: Skeleton,
    qpos: np.ndarray,
    site_index: np.ndarray,
    targets: np.ndarray,
    weights: np.ndarray,
    *,
    dofs: np.ndarray,
    iterations: int,
    damping: float,
) -> np.ndarray:
    """Batched Levenberg-Marquardt IK: move sites onto targets, hinges kept in their ranges.

    Minimises sum_s w_ts^2 |p_s(q_t) - target_ts|^2 for every frame t at once, over the step
    coordinates `dofs` (of the D = 34: 0-2 root translation, 3-5 root rotation, 6+ hinges).
    Each iteration solves (J^T W J + lambda diag(J^T W J) + eps I) dq = -J^T W r per frame;
    hinges the step would push past a limit are set onto it and held there while the others
    are solved (one active-set pass). lambda is adapted per frame: a step that raises the
    cost is refused and lambda grows 10x; an accepted one divides it by 3.

    Args:
        skeleton: the humanoid's kinematics.
        qpos: (T, 35) start poses (hinges within their ranges).
        site_index: (S',) sites (SITE_NAMES order) with targets.
        targets: (T, S', 3) target positions, metres.
        weights: (T, S') residual weights (0 leaves a site out of a frame).
        dofs: (D',) step coordinates that move.
        iterations: LM iterations.
        damping: the initial lambda.

    Returns:
        (T, 35) fitted qpos.
    """
    root_pos, root_rot, hinges = qpos_to_pose(qpos)
    frames = len(qpos)
    dofs = np.asarray(dofs)
    is_hinge = dofs >= 6
    hinge_of = np.where(is_hinge, dofs - 6, 0)
    lo = np.where(is_hinge, skeleton.ranges[hinge_of, 0], -np.inf)
    hi = np.where(is_hinge, skeleton.ranges[hinge_of, 1], np.inf)
    w2 = weights**2

    def cost_and_parts(rp, rr, hg):
        body_pos, _, axes, sites = skeleton.forward(rp, rr, hg)
        sites = sites[:, site_index]
        residual = sites - targets
        cost = (w2 * (residual**2).sum(-1)).sum(-1)
        return cost, body_pos, axes, sites, residual

    cost, body_pos, axes, sites, residual = cost_and_parts(root_pos, root_rot, hinges)
    lam = np.full(frames, damping)
    eye = np.eye(len(dofs))
    for _ in range(iterations):
        jac = skeleton.jacobian(root_pos, body_pos, axes, sites, site_index)[..., dofs]
        normal = np.einsum("tsik,ts,tsil->tkl", jac, w2, jac)
        gradient = np.einsum("tsik,ts,tsi->tk", jac, w2, residual)
        diagonal = np.diagonal(normal, axis1=1, axis2=2)
        system = normal + (lam[:, None] * diagonal + 1e-9)[:, :, None] * eye
        step = np.linalg.solve(system, -gradient[..., None])[..., 0]
        # Active set: hinges pushed past a limit go onto it and stay; the rest re-solved.
        current = np.where(is_hinge, hinges[:, hinge_of], 0.0)
        clamped = np.clip(current + step, lo, hi)
        held = clamped != current + step
        if held.any():
            fixed = np.where(held, clamped - current, 0.0)
            rhs = -gradient - np.einsum("tkl,tl->tk", system, fixed)
            free_pair = ~held[:, :, None] & ~held[:, None, :]
            system = np.where(free_pair, system, 0.0) + held[:, :, None] * eye
            rhs = np.where(held, fixed, rhs)
            step = np.linalg.solve(system, rhs[..., None])[..., 0]
            step = np.clip(current + np.where(held, fixed, step), lo, hi) - current
        full = np.zeros((frames, 6 + NUM_ACTUATED))
        full[:, dofs] = step
        new_pos = root_pos + full[:, :3]
        new_rot = _rotation_step(root_rot, full[:, 3:6])
        new_hinges = np.clip(hinges + full[:, 6:], skeleton.ranges[:, 0], skeleton.ranges[:, 1])
        new = cost_and_parts(new_pos, new_rot, new_hinges)
        better = new[0] <= cost
        lam = np.where(better, lam / 3.0, lam * 10.0)
        pick = better[:, None]
        root_pos = np.where(pick, new_pos, root_pos)
        root_rot = np.where(pick[:, :, None], new_rot, root_rot)
        hinges = np.where(pick, new_hinges, hinges)
        cost = np.where(better, new[0], cost)
        body_pos = np.where(pick[:, :, None], new[1], body_pos)
        axes = np.where(pick[:, :, None], new[2], axes)
        sites = np.where(pick[:, :, None], new[3], sites)
        residual = np.where(pick[:, :, None], new[4], residual)
    return pose_to_qpos(root_pos, root_rot, hinges)


# ---------------------------------------------------------------------------------------------
# Fit the humanoid


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _perpendicular(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The part of `v` perpendicular to the unit `axis`, both (..., 3)."""
    return v - (v * axis).sum(-1, keepdims=True) * axis


def _frame(first: str, a: np.ndarray, second: str, b: np.ndarray) -> np.ndarray:
    """A rotation whose axis `first` points along `a` and axis `second` as near `b` as it can
    (Gram-Schmidt); axes named "x", "y", "z"; returns (..., 3, 3) with the axes as columns."""
    axes = {first: _unit(a)}
    axes[second] = _unit(_perpendicular(b, axes[first]))
    third = ({"x", "y", "z"} - {first, second}).pop()
    cyclic = {"x": ("y", "z"), "y": ("z", "x"), "z": ("x", "y")}[third]
    axes[third] = np.cross(axes[cyclic[0]], axes[cyclic[1]])
    return np.stack([axes["x"], axes["y"], axes["z"]], axis=-1)


def body_rotations_from_points(points: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """A first guess of the 15 body rotations from BlazePose-order world joints.

    The pelvis stands upright, turned so its y axis runs along the hips (right to left);
    the torso's z axis runs from the abdomen joint to the mid-shoulder point, its y axis
    along the shoulders; the head's y axis along the ears, its x axis towards the nose. A
    limb segment's z axis points from its far joint back to its near one (the limbs hang
    along -z at rest); its bending axis comes from the next segment's direction (forearms
    bend towards the upper arm's +x, shins towards the thigh's -x), with the parent's
    forward axis as a weak fallback for a straight limb. Feet: x from heel to toe, z from
    the sole up to the ankle. Hands follow their forearms.

    Args:
        points: (T, 33, 3) finite world joints, metres.
        skeleton: the humanoid (for the abdomen joint's offset).

    Returns:
        (T, 15, 3, 3) world rotations, BODY_NAMES order.
    """

    def at(name: str) -> np.ndarray:
        return points[:, BLAZEPOSE_33.index(name)]

    rot = np.empty((len(points), NUM_BODIES, 3, 3))
    body = {name: i for i, name in enumerate(BODY_NAMES)}
    up = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (len(points), 3))
    hips = at("left_hip") - at("right_hip")
    rot[:, body["pelvis"]] = _frame("y", hips, "z", up)
    pelvis = rot[:, body["pelvis"]]
    mid_hip = (at("left_hip") + at("right_hip")) / 2
    abdomen = mid_hip + pelvis @ skeleton.offsets[body["torso"]]
    mid_shoulder = (at("left_shoulder") + at("right_shoulder")) / 2
    rot[:, body["torso"]] = _frame(
        "y", at("left_shoulder") - at("right_shoulder"), "z", mid_shoulder - abdomen
    )
    torso = rot[:, body["torso"]]
    mid_ear = (at("left_ear") + at("right_ear")) / 2
    rot[:, body["head"]] = _frame("y", at("left_ear") - at("right_ear"), "x", at("nose") - mid_ear)

    def limb(upper: str, lower: str, near: str, joint: str, far: str, sign: float, parent):
        direction = at(joint) - at(near)
        z = -_unit(direction)
        bend = sign * _perpendicular(at(far) - at(joint), z)
        fallback = _perpendicular(parent[..., 0], z)  # the parent's forward axis
        length = np.linalg.norm(at(far) - at(joint), axis=-1, keepdims=True)
        rot[:, body[upper]] = _frame("z", z, "x", bend + 0.05 * length * _unit(fallback))
        hinge_y = rot[:, body[upper]][..., 1]
        rot[:, body[lower]] = _frame("z", at(joint) - at(far), "y", hinge_y)

    for side in ("right", "left"):
        limb(f"{side}_upper_arm", f"{side}_lower_arm", f"{side}_shoulder", f"{side}_elbow",
             f"{side}_wrist", 1.0, torso)  # fmt: skip
        rot[:, body[f"{side}_hand"]] = rot[:, body[f"{side}_lower_arm"]]
        limb(f"{side}_thigh", f"{side}_shin", f"{side}_hip", f"{side}_knee", f"{side}_ankle",
             -1.0, pelvis)  # fmt: skip
        heel, toe, ankle = at(f"{side}_heel"), at(f"{side}_foot_index"), at(f"{side}_ankle")
        rot[:, body[f"{side}_foot"]] = _frame("x", toe - heel, "z", ankle - heel)
    return rot


def site_targets(points: np.ndarray, face_weight: float) -> tuple[np.ndarray, np.ndarray]:
    """Each humanoid site's target: the mean of the BlazePose landmarks it stands for.

    Args:
        points: (T, 33, 3) world joints.
        face_weight: weight of the head's sites; the others weigh 1.

    Returns:
        targets (T, S, 3) and weights (S,), SITE_NAMES order (sites no landmark maps to
        get weight 0).
    """
    targets = np.zeros((len(points), len(SITE_NAMES), 3))
    weights = np.zeros(len(SITE_NAMES))
    for s, site in enumerate(SITE_NAMES):
        members = [j for j, name in enumerate(BLAZEPOSE_33) if BLAZEPOSE_TO_SITE[name] == site]
        if members:
            targets[:, s] = points[:, members].mean(1)
            weights[s] = face_weight if site in _FACE_SITES else 1.0
    return targets, weights


def fit_humanoid(
    points: np.ndarray,
    bones: BoneLengths,
    *,
    iterations: int,
    damping: float,
    face_weight: float,
) -> np.ndarray:
    """Inverse kinematics of the boxer humanoid (built with `bones`) to 3D joints.

    Every frame at once: `body_rotations_from_points` gives a first pose (hinges wrapped and
    clipped into their ranges), then `solve_ik` moves all 34 degrees of freedom so the sites
    meet the landmarks they stand for (`site_targets`), within the joint limits.

    Args:
        points: (T, 33, 3) BlazePose-order world joints, metres, finite.
        bones: the fighter's segment lengths (the humanoid is built from them).
        iterations, damping: `solve_ik`'s Levenberg-Marquardt iterations and initial damping.
        face_weight: the weight of the face's sites relative to the body's (1).

    Returns:
        (T, 35) qpos, hinges within their ranges.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 3 or p.shape[1:] != (len(BLAZEPOSE_33), 3):
        raise ValueError(f"points must have shape (T, {len(BLAZEPOSE_33)}, 3), got {p.shape}")
    if len(p) == 0 or not np.isfinite(p).all():
        raise ValueError("points must hold at least one frame and be finite")
    if not isinstance(bones, BoneLengths):
        raise TypeError(f"bones must be a BoneLengths, got {type(bones).__name__}")
    skeleton = Skeleton.from_model(mujoco.MjModel.from_xml_string(boxer_mjcf(bones)))
    rotations = body_rotations_from_points(p, skeleton)
    root = p[:, [BLAZEPOSE_33.index("left_hip"), BLAZEPOSE_33.index("right_hip")]].mean(1)
    qpos = qpos_from_body_rotations(root, rotations)
    qpos[:, 7:] = wrap_to_ranges(qpos[:, 7:], skeleton.ranges)
    targets, weights = site_targets(p, face_weight)
    used = np.flatnonzero(weights > 0)
    return solve_ik(
        skeleton,
        qpos,
        used,
        targets[:, used],
        np.broadcast_to(weights[used], (len(p), len(used))),
        dofs=np.arange(6 + NUM_ACTUATED),
        iterations=iterations,
        damping=damping,
    )
