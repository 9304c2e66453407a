"""A live bout: an exported opponent against a partner the client moves, one policy step at a time.

`LiveBout` is one arena of the opponent's training environment (as `tasks.opponent.spar`), with
the opponent driven by its controller (`models.arena.controller`: any kind of opponent folder,
given the bodies and observations each step and reset at each of its starts) and the partner a
puppet (`models.arena.puppet.Puppet`) moved by the client, two ways (docs/spar-protocol.md):
- "commands": the partner's pelvis follows a heading and a speed: it turns towards the heading
  at most `MAX_TURN_RATE` and glides at the speed, its height and tilt as it started. Its limbs
  hold its guard, or, given a partner policy (another opponent folder, e.g. the run's other
  fighter), are driven by that folder's controller through the actuators as in training, with
  the commanded heading as its task input where it was trained for MAAIP's heading task (§5.4).
- "poses": the partner takes each pose (the humanoid's qpos) the client sends, moving to it over
  one step; a pose further than `TELEPORT_M` from the last is a jump, taken with zero velocity.

Either way the partner is kinematic: it pushes and strikes the opponent through the solver's
contacts, but nothing pushes it back (a partner walked into the opponent shoves it over). When
the opponent falls (or the simulation blows up), and when the partner jumps (a pose further
than `TELEPORT_M` from the last: a new start, which could land inside the opponent), the
opponent starts again standing in its guard where the bout's start put it relative to the
partner (1.2 m in front of it, facing it); the partner stays where it is. A partner's fall (the
client's pose lying down) is counted and nothing more.

The server (`flows.spar_server`) calls `command` and `pose` as messages come in and `step` on
its clock; this module knows nothing of sockets or JSON text. No torch is imported here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from models.arena.controller import Seen
from models.arena.env import ArenaEnv
from models.arena.puppet import Puppet
from models.humanoid.boxer import JOINT_RANGES_DEG, BoneLengths
from models.humanoid.kinematics import (
    BODY_NAMES,
    NQ,
    NUM_ACTUATED,
    ROOT_POS,
    ROOT_QUAT,
    heading_yaw,
    wrap_angle,
)
from models.humanoid.observations import BodyState
from tasks.opponent.folder import Opponent
from tasks.opponent.spar import env_config, standing_start

MODES = ("commands", "poses")
MAX_SPEED = 2.0  # m/s: a boxer's footwork; faster is running, not sparring
MAX_TURN_RATE = math.pi  # rad/s: a half turn in a second, as a boxer pivots
TELEPORT_M = 0.5  # a pelvis moving further in one 30 Hz step would move at 15 m/s
HINGE_SLACK = 0.1  # rad a client's hinge may exceed its range by (rounding, other IK)
REACH_M = 20.0  # how far from the centre a partner may be placed
_HINGES = slice(7, NQ)


class BadPose(ValueError):
    """A pose or command the bout refuses; the message says what is wrong, in one line."""


class WrongMode(BadPose):
    """A command in poses mode, or a pose in commands mode."""


@dataclass(frozen=True)
class Fighter:
    """One fighter after a step."""

    role: str  # "opponent" or "partner"
    slot: int
    positions: np.ndarray  # (15, 3) bodies' world positions
    quaternions: np.ndarray  # (15, 4) bodies' world orientations (w, x, y, z)
    qpos: np.ndarray  # (35,)
    heading: float  # world yaw of its facing
    damage_n: float
    fell: bool
    falls: int


@dataclass(frozen=True)
class LiveStep:
    """What one step did: both fighters (opponent first), contacts, whether the bout restarted."""

    step: int
    t: float
    fighters: tuple[Fighter, Fighter]
    contacts: tuple[tuple[str, str, float], ...]  # (opponent's body, partner's body, newtons)
    reset: bool


class LiveBout:
    """One live arena; see the module docstring. Call `close` (or use `with`) when done."""

    def __init__(
        self,
        opponent: Opponent,
        mode: str,
        partner_bones: BoneLengths | None = None,
        partner: Opponent | None = None,
    ):
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        self.opponent = opponent
        # Its own controllers: what one keeps of its episodes is this bout's alone.
        self.controller = opponent.controller.fresh()
        self.mode = mode
        self.slot = opponent.agent
        self.partner_slot = 1 - self.slot
        # The partner's policy drives its limbs in commands mode only: poses set all of it.
        self.partner = partner if mode == "commands" else None
        self.partner_controller = None if self.partner is None else self.partner.controller.fresh()
        bones = list(opponent.bones)
        guards = opponent.guard.copy()
        if partner is not None:
            bones[self.partner_slot] = partner.bones[partner.agent]
            guards[self.partner_slot] = partner.guard[partner.agent]
        if partner_bones is not None:
            bones[self.partner_slot] = partner_bones
        self.bones = (bones[0], bones[1])
        self.config = env_config(opponent)
        self.env = ArenaEnv(self.config, np.random.default_rng(0), self.bones)
        self.start = standing_start(self.env, guards)
        model, index = self.env.model, self.env.index
        self.hinge_range = np.radians(np.array(list(JOINT_RANGES_DEG.values())))  # (28, 2)
        # Contacts and shapes name their body: which of its fighter's 15 bodies owns each geom.
        self._body_of_geom = np.full(model.ngeom, -1)
        for agent in index.agents:
            for k, body in enumerate(agent.body_ids):
                self._body_of_geom[model.geom_bodyid == body] = k
        self.falls = [0, 0]  # by slot
        self.steps = 0
        self._restart()

    def close(self) -> None:
        self.env.close()

    def __enter__(self) -> LiveBout:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---------------------------------------------------------------- inputs

    def command(self, heading: float, speed: float) -> None:
        """Steer the partner (commands mode): a world yaw and a speed in m/s."""
        if self.mode != "commands":
            raise WrongMode("a command in poses mode (send poses)")
        if not math.isfinite(heading):
            raise BadPose(f"heading must be a finite number, got {heading!r}")
        if not (math.isfinite(speed) and 0.0 <= speed <= MAX_SPEED):
            raise BadPose(f"speed must be in [0, {MAX_SPEED}] m/s, got {speed!r}")
        self._heading_target = float(wrap_angle(heading))
        self._speed = float(speed)

    def pose(self, qpos: np.ndarray) -> None:
        """The partner's next pose (poses mode): its (35,) qpos, checked."""
        if self.mode != "poses":
            raise WrongMode("a pose in commands mode (send commands)")
        self._target = self.check_pose(qpos)

    def check_pose(self, qpos) -> np.ndarray:
        """A client's qpos as 35 floats with a unit quaternion and hinges clipped into range;
        BadPose for anything else."""
        try:
            q = np.array(qpos, dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise BadPose(f"qpos must be {NQ} numbers ({error})") from None
        if q.shape != (NQ,):
            raise BadPose(f"qpos must be {NQ} numbers, got shape {q.shape}")
        if not np.isfinite(q).all():
            bad = int(np.flatnonzero(~np.isfinite(q))[0])
            raise BadPose(f"qpos[{bad}] is {q[bad]}")
        norm = float(np.linalg.norm(q[ROOT_QUAT]))
        if norm < 1e-6:
            raise BadPose("qpos[3:7], the pelvis quaternion, is zero")
        q[ROOT_QUAT] /= norm
        low, high = self.hinge_range[:, 0], self.hinge_range[:, 1]
        hinges = q[_HINGES]
        outside = (hinges < low - HINGE_SLACK) | (hinges > high + HINGE_SLACK)
        if outside.any():
            k = int(np.flatnonzero(outside)[0])
            raise BadPose(
                f"qpos[{7 + k}] = {hinges[k]:.3f} rad is outside its joint's range "
                f"[{low[k]:.3f}, {high[k]:.3f}]"
            )
        q[_HINGES] = np.clip(hinges, low, high)
        x, y, z = q[ROOT_POS]
        if math.hypot(x, y) > REACH_M or not -0.1 <= z <= 3.0:
            raise BadPose(
                f"pelvis at ({x:.2f}, {y:.2f}, {z:.2f}) m: it must be within {REACH_M:.0f} m of "
                "the centre and between the floor and 3 m"
            )
        return q

    # ---------------------------------------------------------------- stepping

    def _partner_qpos(self) -> np.ndarray:
        data = self.env.datas[0]
        return data.qpos[self.env.index.agents[self.partner_slot].qpos].copy()

    def _restart(self) -> None:
        """The bout's start: both standing in their guards, 1.2 m apart."""
        self._obs = self.env.reset([0], self.start)
        self._bodies = self._body_states()
        self._reset_controllers(both=True)
        data = self.env.datas[0]
        self._start_opponent = data.qpos[self.env.index.agents[self.slot].qpos].copy()
        self._start_partner = self._partner_qpos()
        self._partner = self._start_partner.copy()
        self._yaw = float(heading_yaw(self._partner[ROOT_QUAT]))
        if self.mode == "commands":
            self._heading_target = self._yaw
            self._speed = 0.0
        else:
            self._target = None

    def _restart_opponent(self) -> None:
        """The opponent standing in its guard where the start put it relative to the partner
        as it is now (module docstring)."""
        turn = float(heading_yaw(self._partner[ROOT_QUAT])) - float(
            heading_yaw(self._start_partner[ROOT_QUAT])
        )
        rotation = Rotation.from_euler("z", turn)
        q = self._start_opponent.copy()
        offset = q[ROOT_POS] - self._start_partner[ROOT_POS]
        q[0:2] = self._partner[0:2] + rotation.apply(offset)[:2]
        q[ROOT_QUAT] = (rotation * Rotation.from_quat(q[ROOT_QUAT], scalar_first=True)).as_quat(
            scalar_first=True
        )
        self._obs = self.env.place(0, self.slot, q)[None]
        self._bodies = self._body_states()
        self._reset_controllers(both=False)

    def _body_states(self) -> BodyState:
        return self.env.body_states(np.zeros(1, dtype=int))

    def _seen(self, slot: int, task: np.ndarray | None = None) -> Seen:
        """What the fighter in ``slot`` sees now."""
        return Seen(
            arenas=np.zeros(1, dtype=int),
            slot=slot,
            bodies=self._bodies,
            observation=self._obs[:, slot],
            partner_observation=self._obs[:, 1 - slot],
            task=task,
        )

    def _reset_controllers(self, *, both: bool) -> None:
        """The opponent's controller (and, at the bout's start, the partner's) starts an
        episode: the opponent was just put in its start."""
        self.controller.reset(self._seen(self.slot))
        if both and self.partner_controller is not None:
            self.partner_controller.reset(self._seen(self.partner_slot))

    def _steered(self, dt: float) -> np.ndarray:
        """The partner's next pose in commands mode."""
        turn = wrap_angle(self._heading_target - self._yaw)
        limit = MAX_TURN_RATE * dt
        self._yaw = float(wrap_angle(self._yaw + np.clip(turn, -limit, limit)))
        q = self._partner.copy()
        q[0] += self._speed * dt * math.cos(self._yaw)
        q[1] += self._speed * dt * math.sin(self._yaw)
        start_yaw = float(heading_yaw(self._start_partner[ROOT_QUAT]))
        turned = Rotation.from_euler("z", self._yaw - start_yaw) * Rotation.from_quat(
            self._start_partner[ROOT_QUAT], scalar_first=True
        )
        q[ROOT_QUAT] = turned.as_quat(scalar_first=True)
        return q

    def step(self) -> LiveStep:
        """One policy step: the opponent acts on what it sees, the partner moves, physics runs."""
        dt = 1.0 / self.config.policy_hz
        if self.mode == "commands":
            target, teleport = self._steered(dt), False
        else:
            target = self._partner if self._target is None else self._target
            teleport = bool(np.linalg.norm(target[ROOT_POS] - self._partner[ROOT_POS]) > TELEPORT_M)
        if teleport:
            self._partner = target
            self.env.place(0, self.partner_slot, target, ground=False)
            self._restart_opponent()
        actions = np.zeros((1, 2, NUM_ACTUATED))
        actions[0, self.slot] = self.controller.act(self._seen(self.slot))[0]
        if self.partner is not None and self.partner_controller is not None:
            task = None
            if self.partner.task_dim:
                targets = np.full((1, 2), self._heading_target)
                task = self.env.heading_inputs(targets)[:, self.partner_slot]
            seen = self._seen(self.partner_slot, task)
            actions[0, self.partner_slot] = self.partner_controller.act(seen)[0]
        puppet = Puppet(self.partner_slot, target[None], root_only=self.partner is not None)
        result = self.env.step(actions, puppet)
        self._partner = self._partner_qpos()
        self._obs, self._bodies = result.observation, result.body
        self.steps += 1
        fell = result.fell[0]
        for slot in (0, 1):
            self.falls[slot] += int(fell[slot])
        fighters = (self._fighter(self.slot, result), self._fighter(self.partner_slot, result))
        contacts = self._contacts()
        restart = teleport or bool(fell[self.slot] or result.unstable[0])
        if result.unstable[0]:
            self._restart()
        elif fell[self.slot]:
            self._restart_opponent()
        return LiveStep(self.steps, self.steps * dt, fighters, contacts, restart)

    def _fighter(self, slot: int, result) -> Fighter:
        data = self.env.datas[0]
        agent = self.env.index.agents[slot]
        qpos = data.qpos[agent.qpos].copy()
        return Fighter(
            role="opponent" if slot == self.slot else "partner",
            slot=slot,
            positions=data.xpos[agent.body_ids].copy(),
            quaternions=data.xquat[agent.body_ids].copy(),
            qpos=qpos,
            heading=float(heading_yaw(qpos[ROOT_QUAT])),
            damage_n=float(result.damage[0, slot]),
            fell=bool(result.fell[0, slot]),
            falls=self.falls[slot],
        )

    def _contacts(self) -> tuple[tuple[str, str, float], ...]:
        """Body pairs of the two fighters touching after the last substep, force summed."""
        model, data = self.env.model, self.env.datas[0]
        owner = self.env.index.agent_of_geom
        force = np.zeros(6)
        pairs: dict[tuple[str, str], float] = {}
        for c in range(data.ncon):
            g = data.contact.geom[c]
            a, b = owner[g[0]], owner[g[1]]
            if a < 0 or b < 0 or a == b:
                continue
            mine, theirs = (g[0], g[1]) if a == self.slot else (g[1], g[0])
            mujoco.mj_contactForce(model, data, c, force)
            key = (BODY_NAMES[self._body_of_geom[mine]], BODY_NAMES[self._body_of_geom[theirs]])
            pairs[key] = pairs.get(key, 0.0) + float(force[0])
        return tuple((a, b, f) for (a, b), f in pairs.items())

    def geoms(self, slot: int) -> list[dict]:
        """A fighter's collision shapes, for drawing it (docs/spar-protocol.md, welcome)."""
        model = self.env.model
        shapes = {
            mujoco.mjtGeom.mjGEOM_SPHERE: "sphere",
            mujoco.mjtGeom.mjGEOM_CAPSULE: "capsule",
            mujoco.mjtGeom.mjGEOM_BOX: "box",
        }
        out = []
        for g in np.flatnonzero(self.env.index.agent_of_geom == slot):
            shape = shapes.get(int(model.geom_type[g]))
            if shape is None:
                continue
            sizes = {"sphere": 1, "capsule": 2, "box": 3}[shape]
            out.append(
                {
                    "body": int(self._body_of_geom[g]),
                    "shape": shape,
                    "size": [round(float(v), 5) for v in model.geom_size[g][:sizes]],
                    "pos": [round(float(v), 5) for v in model.geom_pos[g]],
                    "quat": [round(float(v), 6) for v in model.geom_quat[g]],
                    "rgba": [round(float(v), 3) for v in model.geom_rgba[g]],
                }
            )
        return out
