"""Two boxers in one MuJoCo model: the MAAIP sparring arena (Younes et al. 2023, §5).

`arena_mjcf` puts two `boxer_mjcf` fighters, agent 0 and agent 1, on a floor under a light,
facing each other across the origin, with two cameras for rendering. `arena_index` finds what
the training environment (`models.arena.env`) needs in the compiled model: each fighter's
`HumanoidIndex`, its actuators, its damage targets and its strikers.

Design decisions:
- Collision bits as `models.humanoid.boxer` prescribes: agent 0's geoms have contype 1 and
  conaffinity 2, agent 1's contype 2 and conaffinity 1, so each fighter touches the other
  (1 & 1, 2 & 2) but never itself (1 & 2 = 0); the floor has contype 0 and conaffinity 3 and
  touches both.
- Damage targets are every geom of the head, torso and pelvis bodies (head sphere and neck;
  abdomen, chest and upper chest; pelvis): MAAIP §5.3 counts contact forces on these three
  bodies, and its simulator reports forces per body, not per shape.
- Strikers are the two glove spheres.
- Optional contact sensors (`contact_sensors=True`) report, per agent, the opponent's contacts
  on each damage-target body and the floor's contacts on the whole fighter and on each of
  its `GROUNDED_GEOMS`.
  They exist for `mujoco.rollout`, which returns states and sensor values but no contacts;
  a model stepped from Python reads `MjData.contact` instead and leaves them out (they are
  cheap, but computed at every step whether read or not).
- The physics timestep is an argument: the environment runs 1 / (policy_hz * substeps).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from models.humanoid.boxer import CONTACT_SOLREF, INTEGRATOR, BoneLengths, boxer_mjcf
from models.humanoid.compiled import HumanoidIndex, humanoid_index
from models.humanoid.kinematics import NUM_ACTUATED

NUM_AGENTS = 2
DEFAULT_PREFIXES: tuple[str, str] = ("a0/", "a1/")
# Corner colours of the gloves and trunks: red for agent 0, blue for agent 1.
DEFAULT_RGBA: tuple[tuple[float, ...], tuple[float, ...]] = (
    (0.8, 0.1, 0.1, 1.0),
    (0.1, 0.2, 0.8, 1.0),
)
# Collision bits (contype, conaffinity) of agent 0 and agent 1; see the module docstring.
COLLISION_BITS: tuple[tuple[int, int], tuple[int, int]] = ((1, 2), (2, 1))
FLOOR = "floor"
# Bodies whose geoms take damage (MAAIP §5.3), and the geoms that strike.
DAMAGE_BODIES: tuple[str, ...] = ("head", "torso", "pelvis")
STRIKER_GEOMS: tuple[str, ...] = ("right_glove", "left_glove")
# Geoms that may touch the floor without a fall: the feet, and the shins, whose capsule ends
# in a sphere round the ankle only 2 cm above the sole and grazes the floor when a foot rolls
# over. A knee on the canvas still counts: the thigh's capsule, thicker, reaches lower there.
GROUNDED_GEOMS: tuple[str, ...] = ("right_foot", "left_foot", "right_shin", "left_shin")
# Sensor slots per damage-target body: contacts beyond this many on one body in one physics
# step are not reported. A pair of spheres and capsules makes at most 2 contacts, so 8 covers
# four of the opponent's geoms pressing on one body at once.
DAMAGE_SENSOR_SLOTS = 8


def _fmt(values: Sequence[float]) -> str:
    return " ".join(f"{float(v):.12g}" for v in values)


def _check_pair(name: str, value: Sequence, kind: type | tuple[type, ...]) -> tuple:
    pair = tuple(value)
    if len(pair) != NUM_AGENTS or not all(isinstance(v, kind) for v in pair):
        raise ValueError(f"{name} must be a pair (agent 0, agent 1), got {value!r}")
    return pair


def arena_mjcf(
    bones: tuple[BoneLengths, BoneLengths] = (BoneLengths(), BoneLengths()),  # noqa: B008 (frozen)
    *,
    timestep: float = 1.0 / 60.0,
    separation: float = 1.2,
    prefixes: tuple[str, str] = DEFAULT_PREFIXES,
    rgba: tuple[Sequence[float], Sequence[float]] = DEFAULT_RGBA,
    body_mass: tuple[float | None, float | None] = (None, None),
    contact_sensors: bool = False,
) -> str:
    """MJCF text of two boxers facing each other on a floor.

    At qpos0 agent 0 stands at (-separation / 2, 0) facing +x and agent 1 at
    (+separation / 2, 0) facing -x, soles on z = 0; the world origin lies midway.

    Args:
        bones: segment lengths of agent 0 and agent 1.
        timestep: physics timestep in seconds (1 / (policy_hz * substeps)).
        separation: pelvis-to-pelvis distance at qpos0, metres.
        prefixes: name prefixes of agent 0's and agent 1's elements; distinct, non-empty.
        rgba: glove and trunk colours of agent 0 and agent 1.
        body_mass: kg without gloves per agent; None for the boxer's default (BMI 24).
        contact_sensors: add the contact sensors `mujoco.rollout` needs (see the module
            docstring and `sensor_layout`).

    Returns:
        The MJCF document as a string.

    Raises:
        ValueError: naming the argument that is out of range or of the wrong form.
    """
    bones = _check_pair("bones", bones, BoneLengths)
    prefixes = _check_pair("prefixes", prefixes, str)
    if not all(prefixes) or prefixes[0] == prefixes[1]:
        raise ValueError(f"prefixes must be two distinct non-empty strings, got {prefixes!r}")
    if any(p.startswith(q) for p in prefixes for q in prefixes if p != q):
        raise ValueError(f"prefixes must not start with one another, got {prefixes!r}")
    rgba = _check_pair("rgba", rgba, Sequence)
    body_mass = _check_pair("body_mass", body_mass, (int, float, type(None)))
    if not (isinstance(timestep, int | float) and math.isfinite(timestep) and timestep > 0):
        raise ValueError(f"timestep must be a finite positive number of seconds, got {timestep!r}")
    if not (isinstance(separation, int | float) and math.isfinite(separation) and separation > 0):
        raise ValueError(f"separation must be a finite positive distance, got {separation!r}")

    root = ET.Element("mujoco", model="arena")
    ET.SubElement(root, "compiler", angle="radian", autolimits="true")
    ET.SubElement(root, "option", timestep=f"{float(timestep):.12g}", integrator=INTEGRATOR)
    visual = ET.SubElement(root, "visual")
    ET.SubElement(visual, "global", offwidth="1280", offheight="720")
    ET.SubElement(visual, "headlight", ambient="0.3 0.3 0.3", diffuse="0.4 0.4 0.4")
    asset = ET.SubElement(root, "asset")
    ET.SubElement(
        asset,
        "texture",
        name="canvas",
        type="2d",
        builtin="checker",
        rgb1="0.62 0.62 0.66",
        rgb2="0.55 0.55 0.6",
        width="256",
        height="256",
    )
    ET.SubElement(asset, "material", name="canvas", texture="canvas", texrepeat="8 8")
    worldbody = ET.SubElement(root, "worldbody")
    ET.SubElement(
        worldbody, "light", name="light", pos="0 0 5", dir="0 0 -1", diffuse="0.7 0.7 0.7"
    )
    ET.SubElement(
        worldbody,
        "geom",
        name=FLOOR,
        type="plane",
        size="0 0 0.05",
        material="canvas",
        contype="0",
        conaffinity=str(COLLISION_BITS[0][0] | COLLISION_BITS[1][0]),
        condim="3",
        solref=_fmt(CONTACT_SOLREF),
    )
    # A broadcast-style side view (the fighters in profile) and a view from above. The side
    # camera looks along +y and 4 deg down: its y axis (0, 0.075, 1) tilts it.
    ET.SubElement(worldbody, "camera", name="side", pos="0 -4 1.4", xyaxes="1 0 0 0 0.075 1")
    ET.SubElement(worldbody, "camera", name="overhead", pos="0 0 6", xyaxes="1 0 0 0 1 0")
    actuator = ET.SubElement(root, "actuator")

    for agent in range(NUM_AGENTS):
        contype, conaffinity = COLLISION_BITS[agent]
        tree = ET.fromstring(
            boxer_mjcf(
                bones[agent],
                prefix=prefixes[agent],
                rgba=rgba[agent],
                body_mass=body_mass[agent],
                contype=contype,
                conaffinity=conaffinity,
            )
        )
        pelvis = tree.find("worldbody/body")
        assert pelvis is not None
        x = separation / 2 * (-1 if agent == 0 else 1)
        pelvis.set("pos", _fmt((x, 0.0, bones[agent].hip_height)))
        if agent == 1:
            pelvis.set("quat", "0 0 0 1")  # half a turn about z: facing -x
        worldbody.append(pelvis)
        source_actuators = tree.find("actuator")
        assert source_actuators is not None
        actuator.extend(list(source_actuators))

    if contact_sensors:
        sensor = ET.SubElement(root, "sensor")
        for agent in range(NUM_AGENTS):
            me, other = prefixes[agent], prefixes[1 - agent]
            for body in DAMAGE_BODIES:
                ET.SubElement(
                    sensor,
                    "contact",
                    name=f"{me}damage_{body}",
                    body1=me + body,
                    subtree2=other + "pelvis",
                    num=str(DAMAGE_SENSOR_SLOTS),
                    data="found force",
                    reduce="maxforce",
                )
            ET.SubElement(sensor, "contact", name=f"{me}floor", geom1=FLOOR, subtree2=me + "pelvis")
            for geom in GROUNDED_GEOMS:
                ET.SubElement(
                    sensor, "contact", name=f"{me}floor_{geom}", geom1=FLOOR, geom2=me + geom
                )
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")


@dataclass(frozen=True, eq=False)
class SensorLayout:
    """Where `arena_mjcf(contact_sensors=True)`'s sensors lie in `MjData.sensordata`.

    Attributes:
        damage: (2, 3) sensordata address of each agent's damage sensors (head, torso,
            pelvis); each holds DAMAGE_SENSOR_SLOTS slots of (found, normal force, two
            tangential forces).
        floor: (2,) address of each agent's floor-contact count (any of its geoms).
        grounded: (2, 4) addresses of each agent's floor-contact counts of its GROUNDED_GEOMS.
    """

    damage: np.ndarray
    floor: np.ndarray
    grounded: np.ndarray


@dataclass(frozen=True, eq=False)
class ArenaIndex:
    """What the environment needs of a compiled arena.

    Attributes:
        agents: each agent's HumanoidIndex (agent 0, agent 1).
        actuators: (2, 28) actuator ids per agent, in JOINT_LAYOUT order (contiguous).
        damage_geoms: per agent, the geom ids of its head, torso and pelvis bodies.
        striker_geoms: (2, 2) geom ids of each agent's right and left glove.
        grounded_geoms: (2, 4) geom ids of each agent's GROUNDED_GEOMS (feet and shins).
        head_geoms: (2,) geom id of each agent's head sphere.
        agent_of_geom: (ngeom,) 0 or 1 for each fighter's geoms, -1 for the floor and others.
        floor_geom: the floor's geom id.
        sensors: the contact sensors' layout, or None if the model has none.
    """

    agents: tuple[HumanoidIndex, HumanoidIndex]
    actuators: np.ndarray
    damage_geoms: tuple[np.ndarray, np.ndarray]
    striker_geoms: np.ndarray
    grounded_geoms: np.ndarray
    head_geoms: np.ndarray
    agent_of_geom: np.ndarray
    floor_geom: int
    sensors: SensorLayout | None


def _id(model: mujoco.MjModel, kind: mujoco.mjtObj, name: str, what: str) -> int:
    index = mujoco.mj_name2id(model, kind, name)
    if index < 0:
        raise ValueError(f"model has no {what} {name!r}")
    return int(index)


def arena_index(
    model: mujoco.MjModel, *, prefixes: tuple[str, str] = DEFAULT_PREFIXES
) -> ArenaIndex:
    """Find both fighters of an `arena_mjcf` model.

    Raises:
        ValueError: naming the missing element or the actuators out of order.
    """
    geom, body, actuator, sensor = (
        mujoco.mjtObj.mjOBJ_GEOM,
        mujoco.mjtObj.mjOBJ_BODY,
        mujoco.mjtObj.mjOBJ_ACTUATOR,
        mujoco.mjtObj.mjOBJ_SENSOR,
    )
    agents = tuple(humanoid_index(model, prefix=p) for p in prefixes)
    actuators = np.empty((NUM_AGENTS, NUM_ACTUATED), dtype=int)
    agent_of_geom = np.full(model.ngeom, -1, dtype=int)
    damage = []
    for a, (prefix, index) in enumerate(zip(prefixes, agents, strict=True)):
        first = _id(model, actuator, prefix + "abdomen_y", "actuator")
        actuators[a] = np.arange(first, first + NUM_ACTUATED)
        # Position servos act on their joint's qpos: actuator k must drive hinge k.
        hinge_qpos = model.jnt_qposadr[model.actuator_trnid[actuators[a], 0]]
        if not np.array_equal(hinge_qpos, np.arange(7, 7 + NUM_ACTUATED) + index.qpos_start):
            raise ValueError(f"actuators of {prefix!r} are not in JOINT_LAYOUT order")
        mine = np.isin(model.geom_bodyid, index.body_ids)
        agent_of_geom[mine] = a
        targets = [_id(model, body, prefix + b, "body") for b in DAMAGE_BODIES]
        damage.append(np.flatnonzero(np.isin(model.geom_bodyid, targets)))
    sensors = None
    if mujoco.mj_name2id(model, sensor, prefixes[0] + "floor") >= 0:

        def address(name: str) -> int:
            return int(model.sensor_adr[_id(model, sensor, name, "sensor")])

        sensors = SensorLayout(
            damage=np.array([[address(f"{p}damage_{b}") for b in DAMAGE_BODIES] for p in prefixes]),
            floor=np.array([address(f"{p}floor") for p in prefixes]),
            grounded=np.array(
                [[address(f"{p}floor_{g}") for g in GROUNDED_GEOMS] for p in prefixes]
            ),
        )
    return ArenaIndex(
        agents=agents,  # type: ignore[arg-type]
        actuators=actuators,
        damage_geoms=(damage[0], damage[1]),
        striker_geoms=np.array(
            [[_id(model, geom, p + g, "geom") for g in STRIKER_GEOMS] for p in prefixes]
        ),
        grounded_geoms=np.array(
            [[_id(model, geom, p + g, "geom") for g in GROUNDED_GEOMS] for p in prefixes]
        ),
        head_geoms=np.array([_id(model, geom, p + "head", "geom") for p in prefixes]),
        agent_of_geom=agent_of_geom,
        floor_geom=_id(model, geom, FLOOR, "geom"),
        sensors=sensors,
    )
