"""Step 3 of the lift: what a body cannot do, removed in MuJoCo.

`cleanup` removes jitter (a zero-phase Gaussian filter on qpos), feet through or above the floor
during contact and foot skating (the root follows the contact feet to their anchors on the
floor, then leg IK pins each contact foot there with smooth blending), one fighter inside the
other (the roots are pushed apart along the line between them, minimally and smoothly, with
geom-geom depths from capsule distances checked against MuJoCo's contacts in the tests), and
any remaining floor penetration of any geom. qvel comes from `mj_differentiatePos`.
`cleanup_pair` does both fighters of a shot.

Shape letters: T frames, G geoms, D degrees of freedom. Units: metres, seconds, radians. World
frame: z up, floor z = 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import mujoco
import numpy as np

from models.humanoid.compiled import HumanoidIndex, humanoid_index, keypoint_positions, velocities
from models.humanoid.fitting import Skeleton, qpos_to_pose, solve_ik, wrap_to_ranges
from models.humanoid.kinematics import JOINT_LAYOUT, NQ, NV, ROOT_POS, ROOT_QUAT, SITE_NAMES
from models.humanoid.motion import (
    check_array,
    check_fps,
    clean_runs,
    gaussian_smooth,
    horizontal_speed,
    runs,
)
from tasks.lift.config import LiftConfig
from tasks.lift.metrics import (
    foot_skating_cm_per_frame,
    jitter_m_s2,
)


@dataclass(frozen=True, eq=False)
class Cleaned:
    """One fighter's humanoid motion after physics cleanup.

    Attributes:
        qpos: (T, 35) humanoid configurations (root position, root quaternion w-x-y-z,
            28 hinge angles within their ranges).
        qvel: (T, 34) velocities at the same frames: root linear velocity (world), root
            angular velocity (pelvis frame), hinge rates; central differences.
        points: (T, 33, 3) the humanoid's sites standing for the BlazePose landmarks, metres.
        contacts: (T, 2) bool, left and right foot in contact as the cleanup used them.
        settle: (T,) how far `settle_on_floor` lowered the root in each frame, metres.
        metrics: name -> value, before and after (``*_before``, ``*_after``):
            ``floor_penetration_mm`` (deepest geom below the floor, max over frames),
            ``foot_height_cm`` (median over frames of the lower foot's lowest point),
            ``foot_skating_cm_per_frame`` (`tasks.lift.metrics.foot_skating_cm_per_frame`,
            the height-weighted FSE, on the heel-toe midpoints of the humanoid's feet),
            ``contact_slide_cm_per_frame`` (mean horizontal slide of those midpoints for
            feet in contact in two consecutive frames, by the contacts used),
            ``jitter_m_s2`` (`tasks.lift.metrics.jitter_m_s2` of the landmarks),
            ``interpenetration_mm`` (deepest overlap with the other fighter, max over
            frames; only with one); and ``contact_share`` and ``floor_settle_cm`` (median
            drop of `settle_on_floor`).
    """

    qpos: np.ndarray
    qvel: np.ndarray
    points: np.ndarray
    contacts: np.ndarray
    settle: np.ndarray
    metrics: dict[str, float]


def _max_then_mean(values: np.ndarray, half: int) -> np.ndarray:
    """A smooth upper envelope: a running max then a running mean, both over 2 half + 1 frames.

    Every output sample is >= the input at its frame (each running max that the mean averages
    covers the frame), so a correction that must reach at least `values` still does.

    Args:
        values: (T,) samples.
        half: half-width in frames; 0 returns a copy.
    """
    v = np.asarray(values, dtype=np.float64)
    if half <= 0 or len(v) == 0:
        return v.copy()
    padded = np.pad(v, half, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
    peak = windows.max(axis=1)
    padded = np.pad(peak, half, mode="edge")
    return np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1).mean(axis=1)


# ---------------------------------------------------------------------------------------------
# Cleanup: geometry of the humanoid's geoms in MuJoCo


@dataclass(frozen=True, eq=False)
class GeomPoses:
    """World poses of one humanoid's geoms over a clip, from MuJoCo's kinematics.

    Attributes:
        kind: (G,) mjtGeom types (capsule, sphere or box).
        size: (G, 3) MuJoCo geom sizes.
        pos: (T, G, 3) centres, metres.
        rot: (T, G, 3, 3) orientations.
        foot: (2, ) geom index (into G) of the left and right foot boxes.
    """

    kind: np.ndarray
    size: np.ndarray
    pos: np.ndarray
    rot: np.ndarray
    foot: tuple[int, int]


def _check_model(name: str, model: mujoco.MjModel) -> HumanoidIndex:
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"{name} must be a mujoco.MjModel, got {type(model).__name__}")
    index = humanoid_index(model)
    if model.nq != NQ or model.nv != NV:
        raise ValueError(
            f"{name} must hold one boxer and nothing else that moves (nq {NQ}, nv {NV}), "
            f"got nq {model.nq}, nv {model.nv}"
        )
    return index


def geom_poses(model: mujoco.MjModel, qpos: np.ndarray) -> GeomPoses:
    """The boxer's geoms (not the floor's) in every frame, by `mj_kinematics`.

    Args:
        model: a model holding one boxer (prefix "").
        qpos: (T, 35).
    """
    index = humanoid_index(model)
    geoms = np.flatnonzero(np.isin(model.geom_bodyid, index.body_ids))
    data = mujoco.MjData(model)
    pos = np.empty((len(qpos), len(geoms), 3))
    rot = np.empty((len(qpos), len(geoms), 3, 3))
    for frame, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        pos[frame] = data.geom_xpos[geoms]
        rot[frame] = data.geom_xmat[geoms].reshape(-1, 3, 3)
    names = [model.geom(int(g)).name for g in geoms]
    return GeomPoses(
        kind=model.geom_type[geoms].copy(),
        size=model.geom_size[geoms].copy(),
        pos=pos,
        rot=rot,
        foot=(names.index("left_foot"), names.index("right_foot")),
    )


_BOX_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)


def lowest_points(poses: GeomPoses) -> np.ndarray:
    """Height of each geom's lowest point: (T, G) metres.

    Spheres: centre z - radius; capsules: the lower end's z - radius; boxes: the lowest of
    the 8 corners.
    """
    z = poses.pos[..., 2]
    radius = poses.size[:, 0]
    reach = np.zeros_like(z)
    capsule = poses.kind == mujoco.mjtGeom.mjGEOM_CAPSULE
    box = poses.kind == mujoco.mjtGeom.mjGEOM_BOX
    # Capsule: half-length size[1] along the geom's z axis.
    reach = np.where(capsule, np.abs(poses.rot[..., 2, 2]) * poses.size[:, 1], reach)
    corner_z = np.einsum("tgj,gcj->tgc", poses.rot[..., 2, :], _BOX_CORNERS * poses.size[:, None])
    low = z - reach - np.where(box, 0.0, radius)
    return np.where(box, z + corner_z.min(-1), low)


def floor_depth(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """How deep the boxer sinks into the floor (z = 0) in each frame: (T,) metres, the deepest
    geom's lowest point below the floor, 0 where every geom is at or above it.

    Args:
        model: a model holding one boxer (prefix "").
        qpos: (T, 35).
    """
    return np.maximum(-lowest_points(geom_poses(model, qpos)).min(1), 0.0)


def _foot_lowest(poses: GeomPoses) -> np.ndarray:
    """(T, 2) lowest point of the left and right foot boxes."""
    return lowest_points(poses)[:, list(poses.foot)]


def capsules(poses: GeomPoses) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The geoms as capsules: segment ends (T, C, 3) twice and radii (C,), C >= G.

    A capsule stays itself and a sphere is a zero-length capsule. A box becomes capsules
    along its longest axis with its smallest half-size as radius, side by side along its
    middle axis, enough of them to span it (the feet: two sole-thick rods from heel to toe);
    they lie inside the box and miss only its edges and corners (by at most 0.3 radius).
    """
    starts, ends, radii, geoms = [], [], [], []
    for g, (kind, size) in enumerate(zip(poses.kind, poses.size, strict=True)):
        if kind == mujoco.mjtGeom.mjGEOM_BOX:
            order = np.argsort(size)  # smallest, middle, longest half-size
            radius, middle, longest = size[order]
            count = max(1, math.ceil(middle / radius - 1e-9))
            along = np.zeros(3)
            along[order[2]] = longest - radius
            for offset in np.linspace(-(middle - radius), middle - radius, count):
                side = np.zeros(3)
                side[order[1]] = offset
                starts.append(side - along)
                ends.append(side + along)
                radii.append(radius)
                geoms.append(g)
        else:
            half = size[1] if kind == mujoco.mjtGeom.mjGEOM_CAPSULE else 0.0
            starts.append(np.array([0.0, 0.0, -half]))
            ends.append(np.array([0.0, 0.0, half]))
            radii.append(size[0])
            geoms.append(g)
    geoms = np.array(geoms)
    rot, pos = poses.rot[:, geoms], poses.pos[:, geoms]
    a = pos + np.einsum("tcij,cj->tci", rot, np.array(starts))
    b = pos + np.einsum("tcij,cj->tci", rot, np.array(ends))
    return a, b, np.array(radii)


def segment_distances(
    p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points of segments [p1, q1] and [p2, q2], broadcast over leading dimensions.

    Ericson, "Real-Time Collision Detection", 2005, §5.1.9 (ClosestPtSegmentSegment), with
    degenerate (point) segments handled.

    Returns:
        distance (...), closest point on the first (..., 3) and on the second (..., 3).
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = (d1 * d1).sum(-1)
    e = (d2 * d2).sum(-1)
    f = (d2 * r).sum(-1)
    c = (d1 * r).sum(-1)
    b = (d1 * d2).sum(-1)
    eps = 1e-12
    safe_a, safe_e = np.maximum(a, eps), np.maximum(e, eps)
    denom = a * e - b * b
    # General case: the lines' closest s, clamped; then t, and s again if t was clamped.
    s = np.where(denom > eps, np.clip((b * f - c * e) / np.maximum(denom, eps), 0, 1), 0.0)
    t = (b * s + f) / safe_e
    s = np.where(t < 0, np.clip(-c / safe_a, 0, 1), s)
    s = np.where(t > 1, np.clip((b - c) / safe_a, 0, 1), s)
    t = np.clip(t, 0, 1)
    # The second segment is a point: t = 0, s the first's closest to it.
    s = np.where(e <= eps, np.clip(-c / safe_a, 0, 1), s)
    t = np.where(e <= eps, 0.0, t)
    # The first segment is a point: s = 0, t the second's closest to it.
    t = np.where(a <= eps, np.where(e <= eps, 0.0, np.clip(f / safe_e, 0, 1)), t)
    s = np.where(a <= eps, 0.0, s)
    c1 = p1 + s[..., None] * d1
    c2 = p2 + t[..., None] * d2
    return np.linalg.norm(c1 - c2, axis=-1), c1, c2


def interpenetration(
    poses: GeomPoses, other: GeomPoses, offset: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """How deep two fighters' geoms (as `capsules`) go into each other, per frame.

    Args:
        poses, other: the two fighters' geoms over the same T frames.
        offset: (T, 3) translation added to the first fighter's geoms, or None.

    Returns:
        depth (T, C1, C2) metres (negative: apart by that much) and unit normals
        (T, C1, C2, 3) pointing from the second fighter's capsule towards the first's, over
        the `capsules` of each.
    """
    a1, b1, r1 = capsules(poses)
    a2, b2, r2 = capsules(other)
    if offset is not None:
        a1, b1 = a1 + offset[:, None], b1 + offset[:, None]
    dist, c1, c2 = segment_distances(a1[:, :, None], b1[:, :, None], a2[:, None, :], b2[:, None, :])
    normal = (c1 - c2) / np.maximum(dist, 1e-9)[..., None]
    return r1[:, None] + r2[None, :] - dist, normal


# ---------------------------------------------------------------------------------------------
# Cleanup steps


def smooth_qpos(qpos: np.ndarray, sigma: float, ranges: np.ndarray) -> np.ndarray:
    """`gaussian_smooth` of a humanoid motion: root position, root quaternion (signs aligned
    with the previous frame, renormalised) and unwrapped hinge angles (clipped to `ranges`)."""
    out = qpos.copy()
    if sigma <= 0 or len(qpos) < 3:
        return out
    out[:, ROOT_POS] = gaussian_smooth(qpos[:, ROOT_POS], sigma)
    quat = qpos[:, ROOT_QUAT].copy()
    for frame in range(1, len(quat)):
        if quat[frame] @ quat[frame - 1] < 0:
            quat[frame] = -quat[frame]
    quat = gaussian_smooth(quat, sigma)
    out[:, ROOT_QUAT] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    hinges = gaussian_smooth(np.unwrap(qpos[:, 7:], axis=0), sigma)
    out[:, 7:] = wrap_to_ranges(hinges, ranges)
    return out


def _blend_corrections(values: np.ndarray, active: np.ndarray, blend: int) -> np.ndarray:
    """Spread per-frame corrections from `active` frames to their neighbours.

    Between two active runs the correction is interpolated linearly; it fades out over
    `blend` frames (raised cosine) after a run and fades in before one, and is 0 further
    away.

    Args:
        values: (T, D) corrections, used where `active`.
        active: (T,) bool.
        blend: fade length in frames.

    Returns:
        (T, D) corrections, equal to `values` on active frames.
    """
    frames = len(values)
    out = np.zeros_like(values)
    if not active.any():
        return out
    index = np.flatnonzero(active)
    timeline = np.arange(frames)
    for d in range(values.shape[1]):
        out[:, d] = np.interp(timeline, index, values[index, d])
    previous = np.maximum.accumulate(np.where(active, timeline, -(10**9)))
    following = np.minimum.accumulate(np.where(active, timeline, 10**9)[::-1])[::-1]
    distance = np.minimum(timeline - previous, following - timeline).astype(float)
    fade = np.where(
        distance <= 0,
        1.0,
        np.where(distance > blend, 0.0, 0.5 * (1 + np.cos(np.pi * distance / (blend + 1)))),
    )
    return out * fade[:, None]


_FOOT_SITES = {
    side: np.array([SITE_NAMES.index(f"{side}_{s}") for s in ("ankle", "heel", "foot_index")])
    for side in ("left", "right")
}


def _leg_dofs(side: str) -> np.ndarray:
    dofs = []
    for joint in JOINT_LAYOUT:
        if joint.name in (f"{side}_hip", f"{side}_knee", f"{side}_ankle"):
            dofs.extend(range(joint.qpos_start - 1, joint.qpos_start - 1 + joint.dofs))
    return np.array(dofs)


def _foot_shifts(
    model: mujoco.MjModel, skeleton: Skeleton, qpos: np.ndarray, contacts: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each contact foot should go: the translation onto its anchor and the floor.

    A foot's anchor for one contact run is the mean horizontal position of its sole midpoint
    (between the heel and toe sites) over the run; the translation moves the midpoint onto it
    and the foot box's lowest corner onto z = 0.

    Returns:
        shifts (T, 2, 3) (zero outside contact), site positions (T, S, 3) and the feet's
        lowest points (T, 2), for left and right.
    """
    _, _, _, sites = skeleton.forward(*qpos_to_pose(qpos))
    low = _foot_lowest(geom_poses(model, qpos))
    shifts = np.zeros((len(qpos), 2, 3))
    for f, side in enumerate(("left", "right")):
        heel, toe = _FOOT_SITES[side][1:]
        middle = (sites[:, heel, :2] + sites[:, toe, :2]) / 2
        for start, stop in runs(contacts[:, f]):
            shifts[start:stop, f, :2] = middle[start:stop].mean(0) - middle[start:stop]
            shifts[start:stop, f, 2] = -low[start:stop, f]
    return shifts, sites, low


def _follow_feet(
    model: mujoco.MjModel,
    skeleton: Skeleton,
    qpos: np.ndarray,
    contacts: np.ndarray,
    config: LiftConfig,
) -> np.ndarray:
    """Step 1 of `fix_feet`: the root moves (smoothly) as the contact feet should."""
    out = qpos.copy()
    shifts, _, _ = _foot_shifts(model, skeleton, out, contacts)
    any_contact = contacts.any(1)
    count = np.maximum(contacts.sum(1), 1)[:, None]
    root_shift = np.zeros((len(out), 3))
    root_shift[:, :2] = (shifts[..., :2] * contacts[..., None]).sum(1) / count
    root_shift[:, 2] = np.where(contacts, shifts[..., 2], -np.inf).max(1)
    frames = np.arange(len(out))
    for d in range(3):
        root_shift[:, d] = np.interp(frames, frames[any_contact], root_shift[any_contact, d])
    out[:, :3] += gaussian_smooth(root_shift, config.root_follow_sigma_frames)
    return out


def fix_feet(
    model: mujoco.MjModel,
    skeleton: Skeleton,
    qpos: np.ndarray,
    contacts: np.ndarray,
    config: LiftConfig,
    *,
    follow: bool = True,
) -> np.ndarray:
    """Feet on the floor without skating while in contact, mostly by moving the whole body.

    1. The root follows the contact feet: per contact frame, horizontally by the mean of the
       contact feet's `_foot_shifts`, vertically by what brings the lower contact foot to the
       floor; interpolated between contact frames and smoothed (Gaussian,
       `config.root_follow_sigma_frames`). A lift's error is largely a rigid slip of the
       whole body (its depth), which this takes out without bending the legs.
    2. The shifts left after that (anchors recomputed) fade in and out over
       `config.contact_blend_frames` around each run (`_blend_corrections`) and never leave
       a foot below the floor; leg IK (`solve_ik` on both hips, knees and ankles, the three
       foot sites each) moves the feet by them, orientation kept.

    Args:
        model, skeleton: the boxer.
        qpos: (T, 35).
        contacts: (T, 2) bool, left and right.
        config: the settings.
        follow: False skips step 1 (the root stays; only the legs move).

    Returns:
        (T, 35) corrected qpos.
    """
    out = qpos.copy()
    if not contacts.any():
        return out
    if follow:
        out = _follow_feet(model, skeleton, out, contacts, config)
    shifts, sites, low = _foot_shifts(model, skeleton, out, contacts)
    site_index, targets, dofs = [], [], []
    for f, side in enumerate(("left", "right")):
        shift = _blend_corrections(shifts[:, f], contacts[:, f], config.contact_blend_frames)
        shift[:, 2] = np.maximum(shift[:, 2], -low[:, f])  # never below the floor
        site_index.append(_FOOT_SITES[side])
        targets.append(sites[:, _FOOT_SITES[side]] + shift[:, None])
        dofs.append(_leg_dofs(side))
    site_index = np.concatenate(site_index)
    return solve_ik(
        skeleton,
        out,
        site_index,
        np.concatenate(targets, axis=1),
        np.ones((len(out), len(site_index))),
        dofs=np.concatenate(dofs),
        iterations=config.cleanup_ik_iterations,
        damping=config.ik_damping,
    )


def separation_offsets(
    poses: GeomPoses,
    other: GeomPoses,
    root: np.ndarray,
    other_root: np.ndarray,
    config: LiftConfig,
    *,
    iterations: int = 16,
    reach: float = 2.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal root offsets that end two fighters' overlap, minimally and smoothly.

    The fighters move apart along the horizontal line between their roots (u, from the
    other to this one). Per frame, bisection finds the least separation s_t (up to `reach`)
    after which no pair of geoms (`interpenetration`) is closer than
    `config.separation_margin_m`; s is then made smooth by `_max_then_mean` (still >= every
    frame's need). This fighter moves by `config.separation_share` of s, the other by the
    rest.

    Args:
        poses, other: the two fighters' geoms over the same frames.
        root, other_root: (T, 3) their root positions.
        config: margin, share and smoothing.
        iterations: bisection steps (the last one's bracket is reach / 2^iterations).
        reach: the largest separation tried, metres.

    Returns:
        (T, 3) offsets for this fighter and (T, 3) for the other (zero z).
    """
    line = root[:, :2] - other_root[:, :2]
    length = np.linalg.norm(line, axis=1, keepdims=True)
    u2 = np.where(length > 1e-6, line / np.maximum(length, 1e-9), np.array([1.0, 0.0]))
    u = np.concatenate([u2, np.zeros((len(u2), 1))], axis=1)

    def clear(separation: np.ndarray) -> np.ndarray:
        depth, _ = interpenetration(poses, other, separation[:, None] * u)
        return depth.max(axis=(1, 2)) <= -config.separation_margin_m

    low = np.zeros(len(u))
    high = np.where(clear(low), 0.0, reach)
    for _ in range(iterations):
        middle = (low + high) / 2
        ok = clear(middle)
        high = np.where(ok, middle, high)
        low = np.where(ok, low, middle)
    need = _max_then_mean(high, config.separation_smooth_frames)
    share = config.separation_share
    return share * need[:, None] * u, -(1 - share) * need[:, None] * u


def _separate(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    other: GeomPoses,
    other_qpos: np.ndarray,
    other_shift: np.ndarray,
    config: LiftConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """`separation_offsets` against the other fighter as moved by `other_shift` so far;
    returns this fighter's moved qpos and the other's total assumed shift."""
    shifted = GeomPoses(other.kind, other.size, other.pos + other_shift[:, None], other.rot,
                        other.foot)  # fmt: skip
    mine, theirs = separation_offsets(
        geom_poses(model, qpos),
        shifted,
        qpos[:, :3],
        other_qpos[:, :3] + other_shift,
        config,
    )
    out = qpos.copy()
    out[:, :3] += mine
    return out, other_shift + theirs


def lift_above_floor(model: mujoco.MjModel, qpos: np.ndarray, half: int) -> np.ndarray:
    """Raise the root by the least smooth amount (`_max_then_mean`) that puts every geom's
    lowest point at or above the floor in every frame."""
    out = qpos.copy()
    depth = floor_depth(model, out)
    if depth.max() > 0:
        out[:, 2] += _max_then_mean(depth, half)
    return out


def settle_on_floor(
    model: mujoco.MjModel, qpos: np.ndarray, half: int
) -> tuple[np.ndarray, np.ndarray]:
    """Lower a fighter who floats onto the floor: nobody stands in the air for long.

    The root comes down by a smooth lower envelope of the lowest geom's height (a running min
    then a running mean over 2 half + 1 frames, the mirror of `_max_then_mean`), so a hop
    shorter than the window keeps its flight and no frame goes below the floor for it.

    Returns the lowered qpos and the drop per frame (T,), metres (>= 0); half 0 lowers nothing.
    """
    if half <= 0:
        return qpos.copy(), np.zeros(len(qpos))
    clearance = np.maximum(lowest_points(geom_poses(model, qpos)).min(1), 0.0)
    drop = -_max_then_mean(-clearance, half)
    out = qpos.copy()
    out[:, 2] -= drop
    return out, drop


def sole_positions(skeleton: Skeleton, qpos: np.ndarray) -> np.ndarray:
    """(T, 2, 3) midpoint of each foot's heel and toe sites (left, right)."""
    _, _, _, sites = skeleton.forward(*qpos_to_pose(qpos))
    return np.stack(
        [
            (sites[:, _FOOT_SITES[s][1]] + sites[:, _FOOT_SITES[s][2]]) / 2
            for s in ("left", "right")
        ],
        axis=1,
    )


def contact_slide(soles: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """How far each foot slides along the floor while in contact, frame to frame.

    Args:
        soles: (T, 2, 3) sole points of the left and right foot (`sole_positions`), metres.
        contacts: (T, 2) bool, each foot in contact.

    Returns:
        (T - 1, 2) horizontal distance in metres from frame t to t + 1 of each foot in
        contact in both frames; NaN for the others (a foot in the air does not skate).
    """
    both = contacts[1:] & contacts[:-1]
    slide = np.linalg.norm(soles[1:, :, :2] - soles[:-1, :, :2], axis=-1)
    return np.where(both, slide, np.nan)


def _motion_metrics(
    model: mujoco.MjModel,
    skeleton: Skeleton,
    qpos: np.ndarray,
    contacts: np.ndarray,
    fps: float,
) -> dict[str, float]:
    """The plausibility numbers `Cleaned.metrics` reports for one motion."""
    points = keypoint_positions(model, qpos)
    soles = sole_positions(skeleton, qpos)
    slide = contact_slide(soles, contacts)
    return {
        "floor_penetration_mm": float(floor_depth(model, qpos).max() * 1000),
        "foot_height_cm": float(np.median(_foot_lowest(geom_poses(model, qpos)).min(1)) * 100),
        "foot_skating_cm_per_frame": (foot_skating_cm_per_frame(soles) if len(qpos) >= 2 else 0.0),
        "contact_slide_cm_per_frame": (
            float(np.nanmean(slide) * 100) if np.isfinite(slide).any() else 0.0
        ),
        "jitter_m_s2": jitter_m_s2(points, fps) if len(qpos) >= 3 else 0.0,
    }


def cleanup(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    contacts: np.ndarray,
    *,
    fps: float,
    config: LiftConfig = LiftConfig(),  # noqa: B008 (frozen, so a safe default)
    other_qpos: np.ndarray | None = None,
    other_model: mujoco.MjModel | None = None,
) -> Cleaned:
    """Remove from one fighter's humanoid motion what a body cannot do.

    In order:
    1. jitter: `smooth_qpos`, hinges kept in their ranges; a fighter floating above the floor
       for longer than `config.floor_settle_s` lowered onto it (`settle_on_floor`);
    2. contacts: `contacts` joined with those MuJoCo's foot geoms show (lowest box corner
       below `config.contact_height_m`, sole slower than `config.contact_speed_m_s`),
       cleaned of short runs (`clean_runs`);
    3. with another fighter, its overlap pushed out (`separation_offsets`; this fighter makes
       `config.separation_share` of it and assumes the other makes the rest);
    4. feet on the floor without skating (`fix_feet`);
    5. with another fighter, what overlap step 4 brought back pushed out again, the contact
       feet pinned again by the legs alone, and a last push;
    6. any geom still below the floor lifted (`lift_above_floor`), qvel (`velocities`).

    The other fighter is taken as given (`other_qpos`), so the overlap is gone exactly when
    its final motion is passed with `separation_share` = 1; `cleanup_pair` does that.

    Args:
        model: a compiled model with one boxer (prefix "") and nothing else that moves, e.g.
            `single_scene_mjcf(bones)`; nq must be 35.
        qpos: (T, 35) its motion (e.g. `fit_humanoid`'s).
        contacts: (T, 2) bool, left and right foot in contact (e.g. `Lifted3D.contacts`).
        fps: frames per second.
        config: the settings.
        other_qpos: (T, 35) the other fighter's motion in the same world, or None.
        other_model: the other fighter's model (its bones); None uses `model`.

    Returns:
        `Cleaned` with qpos, qvel, the humanoid's BlazePose-order points, the contacts used
        and before/after metrics.

    Raises:
        ValueError: naming the argument whose shape or values are wrong.
    """
    _check_model("model", model)
    q = check_array("qpos", qpos, (None, NQ))
    frames = len(q)
    if frames == 0 or not np.isfinite(q).all():
        raise ValueError("qpos must hold at least one frame and be finite")
    c = np.asarray(contacts)
    if c.shape != (frames, 2) or c.dtype != bool:
        raise ValueError(f"contacts must be a (T, 2) = ({frames}, 2) bool array, got {c.shape} "
                         f"{c.dtype}")  # fmt: skip
    fps = check_fps(fps)
    if other_qpos is not None:
        other_model = model if other_model is None else other_model
        _check_model("other_model", other_model)
        other_q = check_array("other_qpos", other_qpos, (frames, NQ))
        if not np.isfinite(other_q).all():
            raise ValueError("other_qpos must be finite")

    skeleton = Skeleton.from_model(model)
    out = smooth_qpos(q, config.smooth_sigma_frames, skeleton.ranges)
    out[:, 7:] = np.clip(out[:, 7:], skeleton.ranges[:, 0], skeleton.ranges[:, 1])
    out, drop = settle_on_floor(model, out, round(config.floor_settle_s * fps / 2))
    poses = geom_poses(model, out)
    soles = sole_positions(skeleton, out)
    speed = horizontal_speed(soles, fps)
    seen = (_foot_lowest(poses) < config.contact_height_m) & (speed < config.contact_speed_m_s)
    used = clean_runs(c | seen, config.contact_min_frames)
    # Measured at the floor: a floating foot's skating weighs nothing, which would flatter it.
    settled = q.copy()
    settled[:, 2] -= drop
    before = _motion_metrics(model, skeleton, settled, used, fps)
    before["foot_height_cm"] = _motion_metrics(model, skeleton, q, used, fps)["foot_height_cm"]
    metrics = {f"{k}_before": v for k, v in before.items()}
    metrics["floor_settle_cm"] = float(np.median(drop) * 100)

    if other_qpos is not None:
        other_poses = geom_poses(other_model, other_q)
        overlap = interpenetration(geom_poses(model, q), geom_poses(other_model, other_q))[0]
        metrics["interpenetration_mm_before"] = float(max(overlap.max(), 0.0) * 1000)
        other_shift = np.zeros((frames, 3))
        out, other_shift = _separate(model, out, other_poses, other_q, other_shift, config)

    out = fix_feet(model, skeleton, out, used, config)
    if other_qpos is not None:
        out, other_shift = _separate(model, out, other_poses, other_q, other_shift, config)
        out = fix_feet(model, skeleton, out, used, config, follow=False)
        out, other_shift = _separate(model, out, other_poses, other_q, other_shift, config)
        overlap = interpenetration(geom_poses(model, out), other_poses, -other_shift)[0]
        metrics["interpenetration_mm_after"] = float(max(overlap.max(), 0.0) * 1000)

    out = lift_above_floor(model, out, config.separation_smooth_frames)
    after = _motion_metrics(model, skeleton, out, used, fps)
    metrics.update({f"{k}_after": v for k, v in after.items()})
    metrics["contact_share"] = float(used.mean())
    return Cleaned(
        qpos=out,
        qvel=velocities(model, out, fps),
        points=keypoint_positions(model, out),
        contacts=used,
        settle=drop,
        metrics=metrics,
    )


def cleanup_pair(
    models: tuple[mujoco.MjModel, mujoco.MjModel],
    qpos: tuple[np.ndarray, np.ndarray],
    contacts: tuple[np.ndarray, np.ndarray],
    *,
    fps: float,
    config: LiftConfig = LiftConfig(),  # noqa: B008 (frozen, so a safe default)
    spans: tuple[tuple[int, int], tuple[int, int]] | None = None,
) -> tuple[Cleaned, Cleaned]:
    """`cleanup` of two fighters of one world, leaving no overlap between them.

    The first is cleaned against the second's input motion and makes
    `config.separation_share` of the separation; the second is then cleaned against the
    first's final motion and makes the rest (share 1), so the two results are checked against
    each other exactly.

    Args:
        models: each fighter's model (see `cleanup`).
        qpos: each fighter's (T_i, 35) motion over its own frames.
        contacts: each fighter's (T_i, 2) bool foot contacts.
        fps: frames per second.
        config: the settings.
        spans: each fighter's frames [start, end) on one timeline (T_i = end - start); None:
            both cover the same frames. Each is cleaned over its own frames only (filtered over
            a frame where it is absent, its first frames took on a stand-in's position 1 km
            away: a fighter entering 48 frames after the other was placed 214 m off); the other
            stands 1 km away where absent, out of reach.

    Returns:
        The two `Cleaned`, in the order given.
    """
    if spans is None:
        spans = ((0, len(qpos[0])), (0, len(qpos[1])))
    first = cleanup(
        models[0],
        qpos[0],
        contacts[0],
        fps=fps,
        config=config,
        other_qpos=_over(qpos[1], spans[1], spans[0]),
        other_model=models[1],
    )
    second = cleanup(
        models[1],
        qpos[1],
        contacts[1],
        fps=fps,
        config=replace(config, separation_share=1.0),
        other_qpos=_over(first.qpos, spans[0], spans[1]),
        other_model=models[0],
    )
    return first, second


def _over(qpos: np.ndarray, span: tuple[int, int], frames: tuple[int, int]) -> np.ndarray:
    """A fighter's ``qpos`` over ``span`` of a timeline, given over ``frames`` of it: where it
    is absent, it stands 1 km away (nothing can touch it), in its nearest pose."""
    (a, b), frame = span, np.arange(*frames)
    out = qpos[np.clip(frame, a, b - 1) - a].copy()
    out[(frame < a) | (frame >= b), 0] += 1000.0
    return out
