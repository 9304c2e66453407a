"""Episode starts: the reference frames they are drawn from, how they are chosen and how a
world is put in one (reference state initialisation, MAAIP §5 after DeepMimic and AMP).

`choose_starts` draws a reference frame per environment with the arena's generator, centres the
pair (`centred_pair`), gives it the velocities `EnvConfig.reset_velocity` says
(`start_velocities`) and stands a share `EnvConfig.standing_share` of them still in the
reference's stance (`standing_like`); `start_world` and `place_agent` put one MuJoCo world in a
start on the host, grounded (`geom_bottoms`) where asked; Warp's worlds are started on the
device from the same choices (`models.arena.stepping.warp`, with `bottoms`).

`ReferenceMotions` lives here, below MAAIP's demonstrations (`models.maaip.demonstrations`
imports it), because the arena starts episodes from it and must not import MAAIP's package.

Shape letters: M reference frames, n environments started.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
from array_api_compat import array_namespace, device
from scipy.spatial.transform import Rotation

from models.arena.config import EnvConfig
from models.arena.mjcf import ArenaIndex
from models.humanoid.compiled import HumanoidIndex
from models.humanoid.kinematics import NQ, NUM_ACTUATED, NV, ROOT_POS, ROOT_QUAT, heading_yaw


@dataclass(frozen=True, eq=False)
class ReferenceMotions:
    """Interaction frames to start episodes from (reference state initialisation).

    Both fighters in one world frame, frame m of agent 0 with frame m of agent 1, as in the
    dataset's interaction clips (`lift_motion` rows of both fighters at one step).

    Attributes:
        qpos0: (M, 35) agent 0's qpos (kinematics' layout).
        qvel0: (M, 34) agent 0's qvel.
        qpos1: (M, 35) agent 1's qpos.
        qvel1: (M, 34) agent 1's qvel.
        stance: (2, 28) the hinge angles each fighter stands in when an episode starts standing
            (`EnvConfig.standing_share`), e.g. its guard (`models.humanoid.stance.guard_pose`);
            None is the rest pose (every hinge at 0).
    """

    qpos0: np.ndarray
    qvel0: np.ndarray
    qpos1: np.ndarray
    qvel1: np.ndarray
    stance: np.ndarray | None = None

    def __post_init__(self) -> None:
        count = None
        for name, width in (("qpos0", NQ), ("qvel0", NV), ("qpos1", NQ), ("qvel1", NV)):
            array = np.array(getattr(self, name), dtype=np.float64)
            if array.ndim != 2 or array.shape[1] != width or len(array) == 0:
                raise ValueError(
                    f"ReferenceMotions.{name} must have shape (M, {width}) with M >= 1, "
                    f"got {array.shape}"
                )
            if count is not None and len(array) != count:
                raise ValueError(
                    f"ReferenceMotions.{name} has {len(array)} frames, qpos0 has {count}: "
                    "every array needs one row per frame"
                )
            if not np.isfinite(array).all():
                raise ValueError(f"ReferenceMotions.{name} must be finite")
            if name.startswith("qpos") and np.any(
                np.linalg.norm(array[:, ROOT_QUAT], axis=1) < 1e-6
            ):
                raise ValueError(f"ReferenceMotions.{name} has a zero root quaternion")
            count = len(array)
            array.setflags(write=False)
            object.__setattr__(self, name, array)
        if self.stance is not None:
            stance = np.array(self.stance, dtype=np.float64)
            if stance.shape != (2, NUM_ACTUATED) or not np.isfinite(stance).all():
                raise ValueError(
                    f"ReferenceMotions.stance must be finite with shape (2, {NUM_ACTUATED}), "
                    f"got {stance.shape}"
                )
            stance.setflags(write=False)
            object.__setattr__(self, "stance", stance)

    @property
    def num_frames(self) -> int:
        return len(self.qpos0)


def geom_bottoms(model: mujoco.MjModel, data: mujoco.MjData, geoms: np.ndarray) -> np.ndarray:
    """The lowest world z of each geom (spheres, capsules and boxes), from current kinematics.

    Args:
        model, data: a model and its data after at least `mj_kinematics`.
        geoms: (G,) geom ids.

    Returns:
        (G,) heights in metres.
    """
    xmat = data.geom_xmat[geoms].reshape(-1, 3, 3)
    return bottoms(model, geoms, data.geom_xpos[geoms], xmat)


def bottoms(model: mujoco.MjModel, geoms: np.ndarray, xpos: np.ndarray, xmat: np.ndarray):
    """`geom_bottoms` from the geoms' world positions ``xpos`` (..., G, 3) and orientations
    ``xmat`` (..., G, 3, 3), of any batch of worlds: NumPy arrays, or torch tensors (Warp's
    worlds on their device), which give tensors there."""
    kinds = model.geom_type[geoms]
    known = (mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_BOX)
    if not np.isin(kinds, known).all():
        bad = [int(g) for g in np.asarray(geoms)[~np.isin(kinds, known)]]
        raise ValueError(f"geom_bottoms handles spheres, capsules and boxes; geoms {bad} are not")
    xp = array_namespace(xpos)
    size = xp.asarray(model.geom_size[geoms], dtype=xpos.dtype, device=device(xpos))
    centre_z = xpos[..., 2]
    zrow = xmat[..., 2, :]  # world z of each local axis
    sphere = centre_z - size[:, 0]
    capsule = centre_z - xp.abs(zrow[..., 2]) * size[:, 1] - size[:, 0]
    box = centre_z - xp.sum(xp.abs(zrow) * size, axis=-1)
    is_sphere = xp.asarray(kinds == mujoco.mjtGeom.mjGEOM_SPHERE, device=device(xpos))
    is_capsule = xp.asarray(kinds == mujoco.mjtGeom.mjGEOM_CAPSULE, device=device(xpos))
    return xp.where(is_sphere, sphere, xp.where(is_capsule, capsule, box))


def start_velocities(qvel: np.ndarray, mode: str, limit: float) -> np.ndarray:
    """Velocities (n, 34) to start episodes with, from the reference's (`EnvConfig.reset_velocity`):
    zeros, the reference's clipped to +-`limit` per coordinate, or the reference's as they are."""
    if mode == "zero":
        return np.zeros_like(qvel)
    if mode == "clip":
        return np.clip(qvel, -limit, limit)
    return qvel.copy()


def standing_like(qpos: np.ndarray, hinges: np.ndarray | None = None) -> np.ndarray:
    """Upright with ``hinges`` (28,) (None: the rest pose, every hinge at 0) where each of
    ``qpos`` (n, 35) stands, facing its heading; the height is left to the caller's grounding."""
    out = np.zeros_like(qpos)
    if hinges is not None:
        out[:, 7:] = hinges
    out[:, ROOT_POS] = qpos[:, ROOT_POS]
    yaw = heading_yaw(qpos[:, ROOT_QUAT])
    out[:, ROOT_QUAT] = Rotation.from_euler("z", yaw[:, None]).as_quat(scalar_first=True)
    return out


def centred_pair(qpos0: np.ndarray, qpos1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both fighters shifted horizontally so that the midpoint of their pelvises is the origin.

    Args:
        qpos0, qpos1: (..., 35) the two fighters' qpos in one world frame.

    Returns:
        The shifted copies.
    """
    shift = (qpos0[..., :2] + qpos1[..., :2]) / 2
    out0, out1 = qpos0.copy(), qpos1.copy()
    out0[..., :2] -= shift
    out1[..., :2] -= shift
    return out0, out1


def choose_starts(
    reference: ReferenceMotions,
    count: int,
    config: EnvConfig,
    rng: np.random.Generator,
    frames: Sequence[int] | np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Starts of ``count`` environments at reference frames (`models.arena.env.ArenaEnv.reset`).

    Each gets a frame drawn uniformly with ``rng`` (or the given ``frames``), both fighters
    placed as in it, shifted horizontally so that the midpoint of their pelvises is the origin;
    velocities follow `EnvConfig.reset_velocity`; a share `EnvConfig.standing_share` of starts
    has both fighters standing still in the reference's stance instead (their guard, or the
    rest pose: `standing_like`). The grounding is the world's (`start_world`).

    Args:
        reference: the frames to start from.
        count: n, the environments to start.
        config: the arena's settings.
        rng: the arena's generator: the frames first, then the standing starts.
        frames: optional frame index per environment, instead of random ones.

    Returns:
        (n, 2, 35) both agents' qpos and (n, 2, 34) their qvel.
    """
    if not isinstance(reference, ReferenceMotions):
        raise ValueError(f"reference must be a ReferenceMotions, got {type(reference).__name__}")
    if frames is None:
        picks = rng.integers(reference.num_frames, size=count)
    else:
        picks = np.asarray(frames).reshape(-1)
        if (
            picks.shape != (count,)
            or not np.issubdtype(picks.dtype, np.integer)
            or (picks.size and (picks.min() < 0 or picks.max() >= reference.num_frames))
        ):
            raise ValueError(
                f"frames must be {count} integers in [0, {reference.num_frames}), got {frames!r}"
            )
    qpos0, qpos1 = centred_pair(reference.qpos0[picks], reference.qpos1[picks])
    qvel = [
        start_velocities(v[picks], config.reset_velocity, config.reset_speed_limit)
        for v in (reference.qvel0, reference.qvel1)
    ]
    if config.standing_share > 0:
        standing = rng.random(count) < config.standing_share
        stance = (None, None) if reference.stance is None else reference.stance
        for qpos, v, hinges in zip((qpos0, qpos1), qvel, stance, strict=True):
            qpos[standing] = standing_like(qpos[standing], hinges)
            v[standing] = 0.0
    return np.stack([qpos0, qpos1], 1), np.stack(qvel, 1)


def start_world(
    model: mujoco.MjModel,
    agents: Sequence[HumanoidIndex],
    data: mujoco.MjData,
    qpos: np.ndarray,
    qvel: np.ndarray,
    ground: Sequence[np.ndarray] | None,
) -> None:
    """One world reset (`mj_resetData`) and started with both agents at ``qpos`` (2, 35) moving
    at ``qvel`` (2, 34); with ``ground`` (each agent's geoms), each fighter is moved up or down
    until its lowest point touches the floor (a lifted frame may float or sink, and a start in
    the air is a drop the policy did not choose). Its kinematics are left to the caller."""
    mujoco.mj_resetData(model, data)
    for a, agent in enumerate(agents):
        data.qpos[agent.qpos] = qpos[a]
        data.qvel[agent.qvel] = qvel[a]
    if ground:
        mujoco.mj_kinematics(model, data)
        for a, agent in enumerate(agents):
            data.qpos[agent.qpos_start + 2] -= geom_bottoms(model, data, ground[a]).min()


def place_agent(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    index: ArenaIndex,
    agent: int,
    qpos: np.ndarray,
    *,
    ground: bool,
) -> None:
    """One agent of one world at rest at ``qpos`` (35,), with ``ground`` moved up or down until
    its lowest point touches the floor, the other agent left as it is (`ArenaEnv.place`)."""
    mine = index.agents[agent]
    data.qpos[mine.qpos] = qpos
    data.qvel[mine.qvel] = 0.0
    if ground:
        mujoco.mj_kinematics(model, data)
        geoms = np.flatnonzero(index.agent_of_geom == agent)
        data.qpos[mine.qpos_start + 2] -= geom_bottoms(model, data, geoms).min()
