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

`read_bvh` reads such a document back into qpos (`qpos_from_channels`, the inverse of
`channels`), e.g. to stream an exported motion to the live sparring server; it refuses any other
hierarchy.
"""

from __future__ import annotations

import warnings

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from models.humanoid.boxer import JOINT_RANGES_DEG, BoneLengths, boxer_mjcf
from models.humanoid.compiled import humanoid_index
from models.humanoid.kinematics import (
    BODY_NAMES,
    NQ,
    NUM_BODIES,
    PARENTS,
    ROOT_POS,
    Y_UP_TO_Z_UP,
    joint_local_rotations,
    qpos_from_body_rotations,
    wrap_angle,
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


# --------------------------------------------------------------------------
# Reading Ringside's own BVH back
# --------------------------------------------------------------------------

_JOINT_CHANNELS = {0: (*POSITION_CHANNELS, *ROTATION_CHANNELS)} | {
    i: ROTATION_CHANNELS for i in range(1, NUM_BODIES)
}
NUM_CHANNELS = 6 + 3 * (NUM_BODIES - 1)


def _hierarchy(tokens: list[str]) -> list[tuple[str, int, tuple[str, ...]]]:
    """(name, parent index, channels) of every joint of a HIERARCHY section's ``tokens`` (after
    the keyword), in file order; ValueError on a malformed or multi-rooted hierarchy."""
    joints: list[tuple[str, int, tuple[str, ...]]] = []
    at = 0

    def take(what: str) -> str:
        nonlocal at
        if at >= len(tokens):
            raise ValueError(f"BVH hierarchy ends early: expected {what}")
        at += 1
        return tokens[at - 1]

    def expect(word: str) -> None:
        found = take(repr(word))
        if found != word:
            raise ValueError(f"BVH hierarchy has {found!r} where {word!r} belongs")

    def offset() -> None:
        expect("OFFSET")
        for _ in range(3):
            value = take("an OFFSET number")
            try:
                float(value)
            except ValueError:
                raise ValueError(f"BVH OFFSET holds {value!r}, not a number") from None

    def joint(parent: int) -> None:
        name = take("a joint name")
        index = len(joints)
        joints.append((name, parent, ()))
        expect("{")
        offset()
        listed: tuple[str, ...] = ()
        while True:
            word = take("'}'")
            if word == "}":
                break
            if word == "CHANNELS":
                count = take("a channel count")
                if not count.isdigit():
                    raise ValueError(f"BVH joint {name!r} has CHANNELS {count!r}")
                listed = tuple(take("a channel name") for _ in range(int(count)))
            elif word == "JOINT":
                joints[index] = (name, parent, listed)
                joint(index)
            elif word == "End":
                expect("Site")
                expect("{")
                offset()
                expect("}")
            else:
                raise ValueError(f"BVH joint {name!r} holds {word!r}")
        joints[index] = (name, parent, listed)

    expect("ROOT")
    joint(-1)
    if at != len(tokens):
        raise ValueError(
            f"BVH hierarchy holds {tokens[at]!r} after its root: one ROOT, Ringside's humanoid, "
            "is read"
        )
    return joints


def _check_ours(joints: list[tuple[str, int, tuple[str, ...]]]) -> None:
    """ValueError naming the first difference between ``joints`` and the hierarchy `bvh_text`
    writes (BODY_NAMES in order, PARENTS, the root's six channels and three for every joint)."""
    names = [name for name, _, _ in joints]
    if len(joints) != NUM_BODIES:
        raise ValueError(
            f"BVH has {len(joints)} joints ({', '.join(names)}); Ringside's humanoid has "
            f"{NUM_BODIES} ({', '.join(BODY_NAMES)})"
        )
    for i, (name, parent, listed) in enumerate(joints):
        if name != BODY_NAMES[i]:
            raise ValueError(
                f"BVH joint {i} is {name!r}; Ringside's humanoid has {BODY_NAMES[i]!r} there "
                f"(joints in order: {', '.join(BODY_NAMES)})"
            )
        if parent != PARENTS[i]:
            has = "the root" if parent < 0 else repr(names[parent])
            wants = "the root" if PARENTS[i] < 0 else repr(BODY_NAMES[PARENTS[i]])
            raise ValueError(f"BVH joint {name!r} hangs from {has}, not from {wants}")
        if listed != _JOINT_CHANNELS[i]:
            raise ValueError(
                f"BVH joint {name!r} has channels {' '.join(listed) or 'none'}; Ringside writes "
                f"{' '.join(_JOINT_CHANNELS[i])}"
            )


def _motion(tokens: list[str]) -> tuple[float, np.ndarray]:
    """(fps, (T, NUM_CHANNELS) values) of a MOTION section's ``tokens`` (after the keyword)."""
    if len(tokens) < 5 or tokens[0] != "Frames:" or tokens[2:4] != ["Frame", "Time:"]:
        raise ValueError("BVH MOTION section must start with 'Frames: N' and 'Frame Time: dt'")
    try:
        frames, frame_time = int(tokens[1]), float(tokens[4])
        values = np.array(tokens[5:], dtype=np.float64)
    except ValueError as error:
        raise ValueError(f"BVH MOTION section holds a non-number: {error}") from None
    if frames < 1:
        raise ValueError(f"BVH has {frames} frames; at least one is read")
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise ValueError(f"BVH Frame Time must be a positive number of seconds, got {frame_time}")
    if len(values) != frames * NUM_CHANNELS:
        raise ValueError(
            f"BVH says {frames} frames of {NUM_CHANNELS} channels ({frames * NUM_CHANNELS} "
            f"numbers) but holds {len(values)} numbers"
        )
    if not np.isfinite(values).all():
        raise ValueError("BVH motion values must be finite")
    return 1.0 / frame_time, values.reshape(frames, NUM_CHANNELS)


def _wrap_into_ranges(hinges: np.ndarray) -> np.ndarray:
    """Hinge angles (..., 28) moved by whole turns to lie within half a turn of their range's
    centre (`JOINT_RANGES_DEG`): every angle within its range is then itself (no range is wider
    than a turn), e.g. a shoulder flexed to -179 deg is not read as +181."""
    centre = np.deg2rad([(lo + hi) / 2 for lo, hi in JOINT_RANGES_DEG.values()])
    return centre + wrap_angle(hinges - centre)


def qpos_from_channels(values: np.ndarray) -> np.ndarray:
    """The inverse of `channels`: one humanoid's qpos from the motion section's values.

    Each joint's Z X Y Euler angles (scipy's `Rotation`, intrinsic) become its rotation in its
    parent's y-up frame, turned into Ringside's z-up world (`Y_UP_TO_Z_UP`); the bodies' world
    rotations then give the hinge angles (`qpos_from_body_rotations`: a 3-DoF joint's y-x-z
    hinges, an elbow's or knee's twist about its axis, the hands' rows unused). Hinge angles are
    taken within a turn of their range (`_wrap_into_ranges`), not clipped to it; the root's
    quaternion has w >= 0.

    Args:
        values: (T, 48) per frame the root's position (cm) then every joint's Z X Y rotation
            (degrees), BODY_NAMES order, y up.

    Returns:
        (T, 35) qpos, metres, z up.
    """
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != NUM_CHANNELS or not len(v):
        raise ValueError(f"values must have shape (T >= 1, {NUM_CHANNELS}), got {v.shape}")
    if not np.isfinite(v).all():
        raise ValueError("values must be finite")
    euler = v[:, 3:].reshape(-1, 3)
    file_frame = Rotation.from_euler("ZXY", euler, degrees=True).as_matrix()
    local = (Y_UP_TO_Z_UP @ file_frame @ _Z_UP_TO_Y_UP).reshape(len(v), NUM_BODIES, 3, 3)
    world = local.copy()
    for i in range(1, NUM_BODIES):
        world[:, i] = world[:, PARENTS[i]] @ local[:, i]
    root = v[:, :3] @ Y_UP_TO_Z_UP.T / CENTIMETRES
    qpos = qpos_from_body_rotations(root, world)
    qpos[:, 7:] = _wrap_into_ranges(qpos[:, 7:])
    return qpos


def read_bvh(text: str) -> tuple[float, np.ndarray]:
    """A BVH document `bvh_text` wrote, read back: (frames per second, (T, 35) qpos).

    The hierarchy must be Ringside's humanoid's (the 15 BODY_NAMES in order, their PARENTS,
    the root's position and Z X Y rotation channels and every other joint's Z X Y rotations);
    any other, e.g. a motion-capture skeleton, is refused with a ValueError naming the first
    difference. OFFSETs and End Sites are not read: the bones are the caller's (a file written
    for other bones still gives the same qpos).
    """
    tokens = text.split()
    if not tokens or tokens[0] != "HIERARCHY":
        raise ValueError("not a BVH document: it must start with HIERARCHY")
    if "MOTION" not in tokens:
        raise ValueError("BVH document has no MOTION section")
    split = tokens.index("MOTION")
    _check_ours(_hierarchy(tokens[1:split]))
    fps, values = _motion(tokens[split + 1 :])
    return fps, qpos_from_channels(values)
