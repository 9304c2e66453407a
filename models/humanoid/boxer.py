"""The boxer humanoid's MJCF, written here and scaled to a fighter's measured bones.

The body is the one MAAIP uses (Younes et al., PACMCGIT 6(3), 2023, §4.2; thesis
§1.1.1): 15 rigid bodies, the pelvis as a free root, 3-DoF joints at the
abdomen, neck, shoulders, hips and ankles, 1-DoF elbows and knees, hands welded
to the forearms and shaped and weighted as gloved fists; 28 actuated degrees of
freedom. Layout, axes and names: `models.humanoid.kinematics`.

Design decisions:
- 3-DoF joints are three hinges (y, x, z), not a ball joint. MuJoCo's position
  servos act on scalar joints only; a ball joint would need torque motors and
  a PD loop in Python at every physics step, which rules out `mujoco.rollout`.
  With hinges, each DoF is a `position` actuator (kp) and the joint's passive
  `damping` (kd): torque = kp (target - q) - kd qdot, the thesis's PD law
  (§1.1.2), with the damping integrated implicitly. The paper's exp-map
  actions become hinge targets with `kinematics.action_to_joint_targets`.
- Gains per joint group in `DEFAULT_GAINS`: kp 300-1000 N m/rad as in public
  AMP humanoids, kd = kp / 10, torque limits of a strong adult, and a little
  armature (reflected rotor inertia) that keeps the light distal bodies stable.
  Legs chosen by measurement (tests/test_standing.py): the rest pose held with
  action noise of std 0.02 on every target fell in 3-4 s with knees at kp 800 and
  ankles at kp 500; the knees buckled (a straight knee at its limit takes only
  flexing targets, so noise bent it on average) and the ankles, at a stiffness
  only 1.4x the body's m g h, let the lean grow. Knees at kp 2500 whose targets
  may reach `KNEE_LOCK_RAD` past straight (the joint's limit holds the knee while
  the servo presses it there, as a locked knee) and ankles at kp 700 with kd 210
  (kd = 0.3 kp) stood 30 s in 127 of 128 trials of the default body (8 seeds x 16
  arenas; one fell at 29.2 s), all 512 of the sample's bodies alone and paired, and
  126 of 128 of a 1.96 m body; with kd 140, 1 of 64 of the default body fell at
  10.7 s. Stiffer ankles turn the ankles' own target noise into lean and fell
  sooner (kp 1000: 18 s on average). The gains are the default body's, scaled to each body's m g h
  (`gain_scale`): on the sample's 1.58 m fighters, unscaled kp 700 ankles lost 3-7
  of 32 trials, kp 500 none.
- Contact stiffness `CONTACT_SOLREF`: the stiffest MuJoCo allows at 120 Hz (a time
  constant of two timesteps); with MuJoCo's default (0.02 s) the same standing
  trials lost 1 in 32 in 30 s, the feet rocking in the softer floor.
- Timestep 1/120 s (`TIMESTEP`) with MuJoCo's `implicitfast` integrator: the
  architecture notes saw 1/60 s diverge and 1/120 s not.
- Masses are segment fractions of the body mass (Winter, "Biomechanics and Motor
  Control of Human Movement", 4th ed., 2009, Table 4.1), spread over each
  body's geoms by volume, so inertias follow the capsule, sphere and box
  shapes. Hands weigh the anatomical 0.6 % plus the glove (10 oz, 0.28 kg).
- Contact: capsules for the trunk and limbs, a sphere for the head, spheres
  for the gloves, boxes for the feet. A boxer does not collide with itself:
  its geoms have contype `contype` and conaffinity `conaffinity` (defaults 1
  and 2); a second fighter built with (2, 1) collides with the first, and a
  floor with contype 0 and conaffinity 3 with both.
- No floor or light: an arena adds them (`single_scene_mjcf` for one boxer).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, fields, replace
from types import MappingProxyType

import numpy as np

from models.humanoid.kinematics import BODY_NAMES, HINGE_NAMES, JOINT_LAYOUT
from models.pose.types import BLAZEPOSE_33

TIMESTEP = 1.0 / 120.0
INTEGRATOR = "implicitfast"
# solref (time constant s, damping ratio) of every geom's contacts; see the module docstring.
CONTACT_SOLREF = (2.0 / 120.0, 1.0)
# How far past straight (radians) a knee's servo target may go: the knee locks on its limit.
KNEE_LOCK_RAD = 0.1

# Standing height (sole to top of head) of the default bones, metres.
DEFAULT_STATURE = 1.78
# Body-mass index used when no body mass is given (a lean, muscular adult).
DEFAULT_BMI = 24.0


# Foot proportions of the default bones: horizontal foot length (heel to toe tip) and ankle
# height as shares of stature, and the share of the foot behind the ankle (`with_plausible_feet`).
FOOT_SHARE = 0.153
ANKLE_SHARE = 0.0393
HEEL_SHARE = 0.235
# Relative deviations from those shares within which a measured foot or ankle height is kept.
FOOT_LENGTH_TOLERANCE = 0.15
ANKLE_TOLERANCE = 0.25


@dataclass(frozen=True)
class BoneLengths:
    """A fighter's segment lengths in metres, the distances between the humanoid's sites.

    The defaults are an adult male of 1.78 m (segment fractions of stature after
    Drillis and Contini, as tabulated by Winter 2009, Fig. 4.1), rounded:
    hips at 0.955 m, shoulder joints at 1.435 m, ears at 1.67 m.

    Attributes:
        pelvis_to_torso: mid-hip (pelvis origin) up to the abdomen joint.
        torso_to_neck: abdomen joint up to the neck joint, which lies at the
            mid-shoulder point (pelvis_to_torso + torso_to_neck = mid-hip to
            mid-shoulder).
        neck_to_head: neck joint up to the head's centre, the mid-ear point.
        head_radius: radius of the head sphere; the ears sit at 0.75 of it.
        shoulder_width: between the two shoulder joint centres.
        upper_arm: shoulder to elbow.
        forearm: elbow to wrist.
        hand: wrist to the knuckles (mid index and pinky knuckle), the glove's centre.
        hip_width: between the two hip joint centres.
        thigh: hip to knee.
        shin: knee to ankle.
        ankle_height: ankle joint above the sole.
        foot: ankle to the tip of the toes (on the sole).
        heel: ankle to the back of the heel (on the sole).
    """

    pelvis_to_torso: float = 0.12
    torso_to_neck: float = 0.36
    neck_to_head: float = 0.235
    head_radius: float = 0.11
    shoulder_width: float = 0.37
    upper_arm: float = 0.33
    forearm: float = 0.26
    hand: float = 0.09
    hip_width: float = 0.20
    thigh: float = 0.44
    shin: float = 0.445
    ankle_height: float = 0.07
    foot: float = 0.22
    heel: float = 0.095

    def __post_init__(self) -> None:
        for field in fields(self):
            value = getattr(self, field.name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(
                    f"BoneLengths.{field.name} must be a finite positive length in metres, "
                    f"got {value!r}"
                )
        for name in ("foot", "heel"):
            if getattr(self, name) <= self.ankle_height:
                raise ValueError(
                    f"BoneLengths.{name} ({getattr(self, name)}) must exceed "
                    f"ankle_height ({self.ankle_height}): both end on the sole below the ankle"
                )

    @property
    def hip_height(self) -> float:
        """Height of the hip joints (the pelvis origin) above the soles when standing straight."""
        return self.ankle_height + self.shin + self.thigh

    @property
    def stature(self) -> float:
        """Standing height in metres: sole to the top of the head sphere."""
        return (
            self.hip_height
            + self.pelvis_to_torso
            + self.torso_to_neck
            + self.neck_to_head
            + self.head_radius
        )

    @property
    def toe_forward(self) -> float:
        """Horizontal distance from the ankle forward to the toe tip."""
        return math.sqrt(self.foot**2 - self.ankle_height**2)

    @property
    def heel_back(self) -> float:
        """Horizontal distance from the ankle back to the heel."""
        return math.sqrt(self.heel**2 - self.ankle_height**2)

    def with_plausible_feet(self) -> BoneLengths:
        """These bones with feet that can carry the body: the heel and the ankle height from the
        body's proportions, the measured foot length kept only where it is plausible.

        A foot measured from video is the least reliable length (BlazePose's heel landmark sits
        on the sole's blurred outline): one fighter of the sample measured a heel 1.1 cm behind
        the ankle, and its humanoid fell backward holding the rest pose. The proportions are the
        default bones' (Drillis and Contini as tabulated by Winter 2009: foot length 0.152-0.153
        of stature, ankle height 0.039), scaled to this fighter's stature: the horizontal foot
        (heel to toe tip) within `FOOT_LENGTH_TOLERANCE` of stature x FOOT_SHARE is kept, else
        that product; the heel takes the default share of it behind the ankle; the ankle height
        within `ANKLE_TOLERANCE` of stature x ANKLE_SHARE is kept, else that product.
        """
        stature = self.stature
        length = self.toe_forward + self.heel_back
        expected = FOOT_SHARE * stature
        if abs(length - expected) > FOOT_LENGTH_TOLERANCE * expected:
            length = expected
        ankle = self.ankle_height
        expected_ankle = ANKLE_SHARE * stature
        if abs(ankle - expected_ankle) > ANKLE_TOLERANCE * expected_ankle:
            ankle = expected_ankle
        back = HEEL_SHARE * length
        return replace(
            self,
            ankle_height=ankle,
            foot=math.hypot(length - back, ankle),
            heel=math.hypot(back, ankle),
        )

    def scaled(self, factor: float) -> BoneLengths:
        """Every length times `factor` (e.g. stature / 1.78 for a taller fighter)."""
        if not (math.isfinite(factor) and factor > 0):
            raise ValueError(f"factor must be a finite positive number, got {factor!r}")
        return replace(self, **{f.name: getattr(self, f.name) * factor for f in fields(self)})

    @classmethod
    def from_points(cls, points: np.ndarray) -> BoneLengths:
        """Estimate a fighter's bones from 3D landmarks over many frames.

        Each length is the median over frames (and over the left and right sides
        for paired limbs) of the distance between the landmarks the humanoid's
        sites stand for, so outlier frames and one-sided errors barely move it.
        The trunk (mid-hip to mid-shoulder) is split between pelvis_to_torso and
        torso_to_neck in the defaults' proportion; bending the abdomen shortens
        it (by 1.2 cm at 30 deg for the default bones), so frames of a crouched
        fighter bias it low. head_radius is the ear distance / 1.5; ankle_height
        is the ankle's distance from the heel-toe line.
        Only distances are used, so any right-handed or left-handed metric frame
        works (BlazePose world landmarks: y down). The feet are then made plausible
        (`with_plausible_feet`).

        Args:
            points: (T, 33, 3) BlazePose-order 3D points in metres; NaN marks a
                missing point.

        Raises:
            ValueError: naming `points` if its shape is wrong, or the length no
                frame measures.
        """
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 3 or p.shape[1:] != (len(BLAZEPOSE_33), 3):
            raise ValueError(
                f"points must have shape (T, {len(BLAZEPOSE_33)}, 3) in BlazePose order, "
                f"got {p.shape}"
            )

        def at(name: str) -> np.ndarray:
            return p[:, BLAZEPOSE_33.index(name)]

        def mid(a: str, b: str) -> np.ndarray:
            return (at(a) + at(b)) / 2

        def dist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
            return np.linalg.norm(a - b, axis=-1)

        def sides(fn: Callable[[str], np.ndarray]) -> np.ndarray:
            return np.concatenate([fn("left"), fn("right")])

        def knuckles(s: str) -> np.ndarray:
            return mid(f"{s}_index", f"{s}_pinky")

        def line_distance(s: str) -> np.ndarray:
            heel, toe, ankle = at(f"{s}_heel"), at(f"{s}_foot_index"), at(f"{s}_ankle")
            along = toe - heel
            cross = np.cross(along, ankle - heel)
            return np.linalg.norm(cross, axis=-1) / np.linalg.norm(along, axis=-1)

        samples = {
            "trunk": dist(mid("left_hip", "right_hip"), mid("left_shoulder", "right_shoulder")),
            "neck_to_head": dist(
                mid("left_shoulder", "right_shoulder"), mid("left_ear", "right_ear")
            ),
            "head_radius": dist(at("left_ear"), at("right_ear")) / 1.5,
            "shoulder_width": dist(at("left_shoulder"), at("right_shoulder")),
            "upper_arm": sides(lambda s: dist(at(f"{s}_shoulder"), at(f"{s}_elbow"))),
            "forearm": sides(lambda s: dist(at(f"{s}_elbow"), at(f"{s}_wrist"))),
            "hand": sides(lambda s: dist(at(f"{s}_wrist"), knuckles(s))),
            "hip_width": dist(at("left_hip"), at("right_hip")),
            "thigh": sides(lambda s: dist(at(f"{s}_hip"), at(f"{s}_knee"))),
            "shin": sides(lambda s: dist(at(f"{s}_knee"), at(f"{s}_ankle"))),
            "ankle_height": sides(line_distance),
            "foot": sides(lambda s: dist(at(f"{s}_ankle"), at(f"{s}_foot_index"))),
            "heel": sides(lambda s: dist(at(f"{s}_ankle"), at(f"{s}_heel"))),
        }
        lengths: dict[str, float] = {}
        for name, values in samples.items():
            finite = values[np.isfinite(values)]
            if finite.size == 0:
                raise ValueError(f"points measure no {name!r} in any frame (all NaN)")
            lengths[name] = float(np.median(finite))
        default = cls()
        share = default.pelvis_to_torso / (default.pelvis_to_torso + default.torso_to_neck)
        trunk = lengths.pop("trunk")
        measured = cls(pelvis_to_torso=trunk * share, torso_to_neck=trunk * (1 - share), **lengths)
        return measured.with_plausible_feet()


@dataclass(frozen=True)
class PDGains:
    """PD servo of one joint group; torque = kp (target - q) - kd qdot, clipped.

    Attributes:
        kp: stiffness in N m / rad (the position actuator's kp).
        kd: damping in N m s / rad (the joint's damping).
        max_torque: actuator torque limit in N m.
        armature: reflected rotor inertia added to each hinge, kg m^2.
    """

    kp: float
    kd: float
    max_torque: float
    armature: float

    def __post_init__(self) -> None:
        for field in fields(self):
            value = getattr(self, field.name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"PDGains.{field.name} must be finite and >= 0, got {value!r}")


DEFAULT_GAINS: Mapping[str, PDGains] = MappingProxyType(
    {
        "abdomen": PDGains(kp=1000.0, kd=100.0, max_torque=300.0, armature=0.02),
        "neck": PDGains(kp=300.0, kd=30.0, max_torque=60.0, armature=0.01),
        "shoulder": PDGains(kp=500.0, kd=50.0, max_torque=150.0, armature=0.02),
        "elbow": PDGains(kp=400.0, kd=40.0, max_torque=100.0, armature=0.01),
        "hip": PDGains(kp=800.0, kd=80.0, max_torque=300.0, armature=0.02),
        "knee": PDGains(kp=2500.0, kd=250.0, max_torque=750.0, armature=0.02),
        "ankle": PDGains(kp=700.0, kd=210.0, max_torque=250.0, armature=0.02),
    }
)

# Joint limits in degrees per hinge. Signs (kinematics' axes): y > 0 bends the trunk
# and head forward, swings the arms and legs backward and points the toes down;
# x > 0 moves a limb towards +y (abduction on the left, adduction on the right);
# elbows and knees flex positive. Shoulders and hips keep |x| < 90 deg, away
# from the y-x-z chain's singularity.
JOINT_RANGES_DEG: Mapping[str, tuple[float, float]] = MappingProxyType(
    {
        "abdomen_y": (-30.0, 75.0),
        "abdomen_x": (-35.0, 35.0),
        "abdomen_z": (-45.0, 45.0),
        "neck_y": (-50.0, 60.0),
        "neck_x": (-40.0, 40.0),
        "neck_z": (-70.0, 70.0),
        "right_shoulder_y": (-180.0, 60.0),
        "right_shoulder_x": (-85.0, 45.0),
        "right_shoulder_z": (-90.0, 90.0),
        "right_elbow": (0.0, 150.0),
        "left_shoulder_y": (-180.0, 60.0),
        "left_shoulder_x": (-45.0, 85.0),
        "left_shoulder_z": (-90.0, 90.0),
        "left_elbow": (0.0, 150.0),
        "right_hip_y": (-120.0, 30.0),
        "right_hip_x": (-60.0, 30.0),
        "right_hip_z": (-45.0, 45.0),
        "right_knee": (0.0, 150.0),
        "right_ankle_y": (-35.0, 50.0),
        "right_ankle_x": (-25.0, 25.0),
        "right_ankle_z": (-30.0, 30.0),
        "left_hip_y": (-120.0, 30.0),
        "left_hip_x": (-30.0, 60.0),
        "left_hip_z": (-45.0, 45.0),
        "left_knee": (0.0, 150.0),
        "left_ankle_y": (-35.0, 50.0),
        "left_ankle_x": (-25.0, 25.0),
        "left_ankle_z": (-30.0, 30.0),
    }
)
assert tuple(JOINT_RANGES_DEG) == HINGE_NAMES

# Segment mass fractions of body mass (Winter 2009, Table 4.1; torso = thorax + abdomen).
MASS_FRACTIONS: Mapping[str, float] = MappingProxyType(
    {
        "pelvis": 0.142,
        "torso": 0.355,
        "head": 0.081,
        "upper_arm": 0.028,
        "lower_arm": 0.016,
        "hand": 0.006,
        "thigh": 0.100,
        "shin": 0.0465,
        "foot": 0.0145,
    }
)

SKIN_RGBA = (0.82, 0.64, 0.52, 1.0)


def _fmt(values: Sequence[float] | float) -> str:
    if isinstance(values, int | float):
        values = (values,)
    return " ".join(f"{float(v):.12g}" for v in values)


def _geom_volume(kind: str, size: Sequence[float], length: float = 0.0) -> float:
    if kind == "sphere":
        return 4 / 3 * math.pi * size[0] ** 3
    if kind == "capsule":
        return math.pi * size[0] ** 2 * length + 4 / 3 * math.pi * size[0] ** 3
    if kind == "box":
        return 8 * size[0] * size[1] * size[2]
    raise ValueError(f"unknown geom type {kind!r}")


@dataclass(frozen=True)
class _Geom:
    name: str
    kind: str
    size: tuple[float, ...]
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    fromto: tuple[float, ...] | None = None
    rgba: tuple[float, ...] = SKIN_RGBA

    @property
    def volume(self) -> float:
        length = 0.0
        if self.fromto is not None:
            length = math.dist(self.fromto[:3], self.fromto[3:])
        return _geom_volume(self.kind, self.size, length)


def _capsule(
    name: str, a: Sequence[float], b: Sequence[float], radius: float, rgba: Sequence[float]
) -> _Geom:
    return _Geom(name, "capsule", (radius,), fromto=(*a, *b), rgba=tuple(rgba))


# One body's plan: position in its parent (m), geoms, and sites by name with positions (m).
_BodyPlan = tuple[tuple[float, float, float], list[_Geom], dict[str, tuple[float, float, float]]]


def _body_geometry(
    bones: BoneLengths, glove_radius: float, rgba: tuple[float, ...]
) -> dict[str, _BodyPlan]:
    """Every body's plan; body frames are aligned with the world at rest."""
    b = bones
    s = b.stature / DEFAULT_STATURE  # scale for thicknesses
    t = b.torso_to_neck
    n = b.neck_to_head
    r = b.head_radius
    out: dict[str, _BodyPlan] = {}
    hw = b.hip_width / 2
    out["pelvis"] = (
        (0.0, 0.0, b.hip_height),
        [_capsule("pelvis", (0, -0.8 * hw, 0.02 * s), (0, 0.8 * hw, 0.02 * s), 0.10 * s, rgba)],
        {},
    )
    sw = b.shoulder_width / 2
    out["torso"] = (
        (0.0, 0.0, b.pelvis_to_torso),
        [
            _capsule(
                "abdomen", (0, -0.06 * s, 0.22 * t), (0, 0.06 * s, 0.22 * t), 0.10 * s, SKIN_RGBA
            ),
            _capsule(
                "chest", (0, -0.07 * s, 0.55 * t), (0, 0.07 * s, 0.55 * t), 0.12 * s, SKIN_RGBA
            ),
            _capsule(
                "upper_chest",
                (0, -0.7 * sw, 0.88 * t),
                (0, 0.7 * sw, 0.88 * t),
                0.065 * s,
                SKIN_RGBA,
            ),
        ],
        {},
    )
    out["head"] = (
        (0.0, 0.0, t),
        [
            _capsule("neck", (0, 0, 0), (0, 0, 0.45 * n), 0.05 * s, SKIN_RGBA),
            _Geom("head", "sphere", (r,), pos=(0.0, 0.0, n)),
        ],
        {
            "nose": (r, 0.0, n - 0.025 * s),
            "left_eye": (0.82 * r, 0.032 * s, n + 0.01 * s),
            "right_eye": (0.82 * r, -0.032 * s, n + 0.01 * s),
            "left_ear": (0.0, 0.75 * r, n),
            "right_ear": (0.0, -0.75 * r, n),
            "mouth_left": (0.86 * r, 0.025 * s, n - 0.065 * s),
            "mouth_right": (0.86 * r, -0.025 * s, n - 0.065 * s),
        },
    )
    for side, sign in (("right", -1.0), ("left", 1.0)):
        out[f"{side}_upper_arm"] = (
            (0.0, sign * sw, t),
            [_capsule(f"{side}_upper_arm", (0, 0, 0), (0, 0, -b.upper_arm), 0.045 * s, SKIN_RGBA)],
            {f"{side}_shoulder": (0.0, 0.0, 0.0)},
        )
        out[f"{side}_lower_arm"] = (
            (0.0, 0.0, -b.upper_arm),
            [_capsule(f"{side}_lower_arm", (0, 0, 0), (0, 0, -b.forearm), 0.037 * s, SKIN_RGBA)],
            {f"{side}_elbow": (0.0, 0.0, 0.0)},
        )
        out[f"{side}_hand"] = (
            (0.0, 0.0, -b.forearm),
            [_Geom(f"{side}_glove", "sphere", (glove_radius,), (0.0, 0.0, -b.hand), rgba=rgba)],
            {f"{side}_wrist": (0.0, 0.0, 0.0), f"{side}_hand": (0.0, 0.0, -b.hand)},
        )
    for side, sign in (("right", -1.0), ("left", 1.0)):
        out[f"{side}_thigh"] = (
            (0.0, sign * hw, 0.0),
            [_capsule(f"{side}_thigh", (0, 0, 0), (0, 0, -b.thigh), 0.07 * s, SKIN_RGBA)],
            {f"{side}_hip": (0.0, 0.0, 0.0)},
        )
        out[f"{side}_shin"] = (
            (0.0, 0.0, -b.thigh),
            [_capsule(f"{side}_shin", (0, 0, 0), (0, 0, -b.shin), 0.05 * s, SKIN_RGBA)],
            {f"{side}_knee": (0.0, 0.0, 0.0)},
        )
        toe, back, h = b.toe_forward, b.heel_back, b.ankle_height
        out[f"{side}_foot"] = (
            (0.0, 0.0, -b.shin),
            [
                _Geom(
                    f"{side}_foot",
                    "box",
                    ((toe + back) / 2, 0.045 * s, h / 2),
                    pos=((toe - back) / 2, 0.0, -h / 2),
                    rgba=(0.15, 0.15, 0.15, 1.0),
                )
            ],
            {
                f"{side}_ankle": (0.0, 0.0, 0.0),
                f"{side}_heel": (-back, 0.0, -h),
                f"{side}_foot_index": (toe, 0.0, -h),
            },
        )
    return out


def gain_scale(body_mass: float, stature: float) -> float:
    """Factor on the gains and torque limits for a body of this mass (kg) and stature (m): the
    ratio of its m g h to the default body's (BMI 24 at the default bones' stature), so that
    every body has the same stiffness relative to the gravity torques it must resist (measured:
    ankles at kp 700 held the default body and fell the sample's 1.58 m fighters, kp 500 the
    reverse; tests/test_standing.py)."""
    default = BoneLengths().stature
    return body_mass * stature / (DEFAULT_BMI * default**3)


def _body_masses(body_mass: float, glove_mass: float) -> dict[str, float]:
    """kg per body: Winter's fractions of `body_mass`, plus the glove on each hand."""
    masses = {}
    for body in BODY_NAMES:
        part = body.split("_", 1)[1] if body.startswith(("left_", "right_")) else body
        masses[body] = MASS_FRACTIONS[part] * body_mass + (glove_mass if part == "hand" else 0.0)
    return masses


def _check_rgba(name: str, rgba: Sequence[float]) -> tuple[float, ...]:
    values = tuple(float(v) for v in rgba)
    if len(values) != 4 or not all(0.0 <= v <= 1.0 for v in values):
        raise ValueError(f"{name} must be 4 numbers in [0, 1], got {rgba!r}")
    return values


def _boxer_tree(
    bones: BoneLengths,
    *,
    name: str,
    prefix: str,
    rgba: Sequence[float],
    body_mass: float | None,
    glove_mass: float,
    glove_radius: float,
    gains: Mapping[str, PDGains],
    contype: int,
    conaffinity: int,
) -> ET.Element:
    if not isinstance(bones, BoneLengths):
        raise TypeError(f"bones must be a BoneLengths, got {type(bones).__name__}")
    if not isinstance(prefix, str) or any(c.isspace() for c in prefix):
        raise ValueError(f"prefix must be a string without whitespace, got {prefix!r}")
    color = _check_rgba("rgba", rgba)
    mass = DEFAULT_BMI * bones.stature**2 if body_mass is None else float(body_mass)
    if not (math.isfinite(mass) and mass > 0):
        raise ValueError(f"body_mass must be a finite positive mass in kg, got {body_mass!r}")
    if not (math.isfinite(glove_mass) and glove_mass >= 0):
        raise ValueError(f"glove_mass must be a finite mass >= 0 in kg, got {glove_mass!r}")
    if not (math.isfinite(glove_radius) and glove_radius > 0):
        raise ValueError(
            f"glove_radius must be a finite positive radius in m, got {glove_radius!r}"
        )
    missing = sorted({j.group for j in JOINT_LAYOUT} - set(gains))
    if missing:
        raise ValueError(f"gains lacks the joint groups {missing}")
    for label, bits in (("contype", contype), ("conaffinity", conaffinity)):
        if not (isinstance(bits, int) and bits >= 0):
            raise ValueError(f"{label} must be an int bit mask >= 0, got {bits!r}")

    geometry = _body_geometry(bones, glove_radius, color)
    masses = _body_masses(mass, glove_mass)
    scale = gain_scale(mass, bones.stature)
    gains = {
        group: replace(g, kp=g.kp * scale, kd=g.kd * scale, max_torque=g.max_torque * scale)
        for group, g in gains.items()
    }
    joints_of = {j.body: j for j in JOINT_LAYOUT}

    root = ET.Element("mujoco", model=name)
    ET.SubElement(root, "compiler", angle="radian", autolimits="true")
    ET.SubElement(root, "option", timestep=_fmt(TIMESTEP), integrator=INTEGRATOR)
    worldbody = ET.SubElement(root, "worldbody")

    def add_body(parent: ET.Element, body: str) -> ET.Element:
        pos, geoms, sites = geometry[body]
        element = ET.SubElement(parent, "body", name=prefix + body, pos=_fmt(pos))
        if body == "pelvis":
            ET.SubElement(element, "freejoint", name=prefix + "root")
        elif body in joints_of:
            joint = joints_of[body]
            gain = gains[joint.group]
            for hinge, axis in zip(joint.hinges, joint.axes, strict=True):
                lo, hi = JOINT_RANGES_DEG[hinge]
                ET.SubElement(
                    element,
                    "joint",
                    name=prefix + hinge,
                    type="hinge",
                    axis=_fmt(axis),
                    range=_fmt((math.radians(lo), math.radians(hi))),
                    damping=_fmt(gain.kd),
                    armature=_fmt(gain.armature),
                )
        density = masses[body] / sum(g.volume for g in geoms)
        for geom in geoms:
            attributes = {
                "name": prefix + geom.name,
                "type": geom.kind,
                "size": _fmt(geom.size),
                "density": _fmt(density),
                "rgba": _fmt(geom.rgba),
                "contype": str(contype),
                "conaffinity": str(conaffinity),
                "condim": "3",
                "solref": _fmt(CONTACT_SOLREF),
            }
            if geom.fromto is not None:
                attributes["fromto"] = _fmt(geom.fromto)
            else:
                attributes["pos"] = _fmt(geom.pos)
            ET.SubElement(element, "geom", attributes)
        for site, site_pos in sites.items():
            ET.SubElement(
                element, "site", name=prefix + site, pos=_fmt(site_pos), size="0.01", group="4"
            )
        return element

    pelvis = add_body(worldbody, "pelvis")
    torso = add_body(pelvis, "torso")
    add_body(torso, "head")
    for side in ("right", "left"):
        upper = add_body(torso, f"{side}_upper_arm")
        add_body(add_body(upper, f"{side}_lower_arm"), f"{side}_hand")
    for side in ("right", "left"):
        thigh = add_body(pelvis, f"{side}_thigh")
        add_body(add_body(thigh, f"{side}_shin"), f"{side}_foot")

    actuators = ET.SubElement(root, "actuator")
    for joint in JOINT_LAYOUT:
        gain = gains[joint.group]
        for hinge in joint.hinges:
            lo, hi = JOINT_RANGES_DEG[hinge]
            lo = math.radians(lo) - (KNEE_LOCK_RAD if joint.group == "knee" else 0.0)
            ET.SubElement(
                actuators,
                "position",
                name=prefix + hinge,
                joint=prefix + hinge,
                kp=_fmt(gain.kp),
                ctrlrange=_fmt((lo, math.radians(hi))),
                forcerange=_fmt((-gain.max_torque, gain.max_torque)),
            )
    return root


def boxer_mjcf(
    bones: BoneLengths = BoneLengths(),  # noqa: B008 (frozen, so a safe default)
    *,
    name: str = "boxer",
    prefix: str = "",
    rgba: Sequence[float] = (0.8, 0.1, 0.1, 1.0),
    body_mass: float | None = None,
    glove_mass: float = 0.28,
    glove_radius: float = 0.06,
    gains: Mapping[str, PDGains] = DEFAULT_GAINS,
    contype: int = 1,
    conaffinity: int = 2,
) -> str:
    """MJCF text of one boxer standing at the origin, facing +x, soles on z = 0.

    The model compiles on its own (it floats: no floor); an arena combines two,
    built with different `prefix`es and collision bits, or attaches them with
    `mujoco.MjSpec.attach`.

    Args:
        bones: the fighter's segment lengths (metres).
        name: the model's name.
        prefix: prepended to every body, joint, geom, site and actuator name
            (e.g. "red/"); `kinematics` functions take the same prefix.
        rgba: colour of the gloves and trunks (the fighter's corner).
        body_mass: kg without gloves; default BMI 24 at the bones' stature.
        glove_mass: kg of each glove, added to the hand (10 oz = 0.28 kg).
        glove_radius: radius of the glove sphere in metres, centred on the knuckles.
        gains: PD gains per joint group (keys: the JointSpec groups) for the default
            body; kp, kd and torque limits are scaled by `gain_scale` for this one.
        contype, conaffinity: collision bit masks of every geom (see module docstring).

    Returns:
        The MJCF document as a string.
    """
    tree = _boxer_tree(
        bones,
        name=name,
        prefix=prefix,
        rgba=rgba,
        body_mass=body_mass,
        glove_mass=glove_mass,
        glove_radius=glove_radius,
        gains=gains,
        contype=contype,
        conaffinity=conaffinity,
    )
    ET.indent(tree)
    return ET.tostring(tree, encoding="unicode")


def single_scene_mjcf(
    bones: BoneLengths = BoneLengths(),  # noqa: B008 (frozen, so a safe default)
    **boxer_kwargs,
) -> str:
    """MJCF text of one boxer on a floor under a light, for tests and previews.

    The floor has contype 0 and every conaffinity bit, so it touches the boxer
    whatever its collision bits.

    Args:
        bones: the fighter's segment lengths (metres).
        **boxer_kwargs: passed to `boxer_mjcf` (name, prefix, rgba, ...).

    Returns:
        The MJCF document as a string.
    """
    boxer_kwargs.setdefault("name", "boxer_scene")
    tree = ET.fromstring(boxer_mjcf(bones, **boxer_kwargs))
    worldbody = tree.find("worldbody")
    assert worldbody is not None
    floor = ET.Element(
        "geom",
        name="floor",
        type="plane",
        size="0 0 0.05",
        rgba="0.55 0.55 0.6 1",
        contype="0",
        conaffinity=str(2**31 - 1),
        condim="3",
        solref=_fmt(CONTACT_SOLREF),
    )
    worldbody.insert(0, floor)
    worldbody.insert(0, ET.Element("light", name="light", pos="0 0 4", dir="0 0 -1"))
    ET.indent(tree)
    return ET.tostring(tree, encoding="unicode")
