"""Sparring: an exported opponent against a second fighter in MuJoCo, with onnxruntime only.

`spar` steps one arena of the training environment (`models.arena.env.ArenaEnv`, the same
physics, observations and fall rule the policy was trained with, read from the opponent's
manifest) with the opponent in its own slot and the partner in the other, each driven by its
controller (`models.arena.controller`: any kind of opponent folder), which is reset at every
start. Both start standing
in their guard (the manifest's `guard`, the pose the policy was trained to start from), 1.2 m
apart and facing each other; a fall (or a blown-up simulation) restarts the bout from there and
is counted. No torch is imported on this path, so an engine
with numpy, MuJoCo and onnxruntime can run it.

Partners: another opponent folder of any kind (e.g. the opponent's trained partner, `ringside
export --agent opponent`), or None, "still", a boxer that holds its guard (the opponent's
trained partner's, on its bones: every PD target at that pose, `tasks.opponent.still`), the
simplest scripted boxer.

Offscreen rendering (`tasks.media`: MuJoCo's renderer through EGL, into an H.264 MP4 that
browsers play) shows the bout from the arena's "side" camera.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from models.arena.config import EnvConfig
from models.arena.controller import Controller, Seen
from models.arena.env import ArenaEnv
from models.arena.starts import ReferenceMotions, standing_like
from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import NQ, NUM_ACTUATED, NV
from models.humanoid.observations import BodyState
from tasks.media import open_video, render_frame
from tasks.opponent.folder import Opponent
from tasks.opponent.still import StillGuard

STILL = "still"


def partner_name(partner: Opponent | None) -> str:
    """The partner as the reports name it: its folder, or "still"."""
    return STILL if partner is None else str(partner.folder)


def seen(obs: np.ndarray, bodies: BodyState, slot: int) -> Seen:
    """What the fighter in ``slot`` of a single arena sees of its observations ``obs``
    (1, 2, 274) and bodies (1, 2)."""
    return Seen(
        arenas=np.zeros(1, dtype=int),
        slot=slot,
        bodies=bodies,
        observation=obs[:, slot],
        partner_observation=obs[:, 1 - slot],
    )


def fighters(
    opponent: Opponent, partner: Opponent | None
) -> tuple[tuple[Controller, Controller], list[BoneLengths], np.ndarray]:
    """The controllers in the opponent's slot and the other, both fighters' bones by slot and
    their guards (2, 28) by slot: the partner's from its own folder, the still boxer's the
    opponent's trained partner's."""
    slot = opponent.agent
    bones = list(opponent.bones)
    guards = opponent.guard.copy()
    if partner is not None:
        bones[1 - slot] = partner.bones[partner.agent]
        guards[1 - slot] = partner.guard[partner.agent]
    other = StillGuard(guards[1 - slot]) if partner is None else partner.controller.fresh()
    return (opponent.controller.fresh(), other), bones, guards


@dataclass(frozen=True)
class SparResult:
    """What a bout did: simulated and wall seconds, falls and damage per fighter."""

    simulated_s: float
    wall_s: float
    policy_steps: int
    falls: tuple[int, int]  # (opponent, partner)
    unstable: int
    damage_received_n: tuple[float, float]  # summed over the bout (opponent, partner)
    frames_rendered: int = 0
    video: str | None = None
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall-clock second of the bout itself (policies, physics and
        the loop); rendering the video is offline work, timed apart in `timings_s`."""
        running = self.wall_s - self.timings_s.get("render", 0.0)
        return self.simulated_s / running if running > 0 else float("inf")

    def as_dict(self) -> dict:
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out["realtime_factor"] = self.realtime_factor
        return out


def env_config(opponent: Opponent) -> EnvConfig:
    """The opponent's training environment, as one arena stepped on the calling thread."""
    settings = dict(opponent.manifest.get("env", {}))
    settings.update(num_envs=1, threads=1, stepping="threads")
    known = {f.name for f in fields(EnvConfig)}
    return EnvConfig(**{k: v for k, v in settings.items() if k in known})


def standing_start(env: ArenaEnv, guards: np.ndarray) -> ReferenceMotions:
    """Both fighters standing still in their ``guards`` (2, 28) where the arena puts them."""
    q = env.model.qpos0
    zero = np.zeros((1, NV))
    qpos0 = standing_like(q[None, :NQ], guards[0])
    qpos1 = standing_like(q[None, NQ:], guards[1])
    return ReferenceMotions(qpos0, zero, qpos1, zero, stance=guards)


def spar(
    opponent: Opponent,
    partner: Opponent | None,
    *,
    seconds: float = 60.0,
    video: Path | None = None,
    size: tuple[int, int] = (640, 360),
    pace: bool = False,
    progress: Callable[[float], None] | None = None,
    forces: Callable[[ArenaEnv, BodyState], np.ndarray] | None = None,
) -> SparResult:
    """Run a bout of `seconds` simulated seconds; see the module docstring.

    Args:
        opponent: the exported fighter, in its own slot (its manifest's agent).
        partner: the fighter in the other slot: an opponent folder, or None for the still
            boxer.
        seconds: simulated length of the bout.
        video: an MP4 to render the bout to (30 frames per simulated second), or None.
        size: the video's width and height in pixels.
        pace: sleep so that the bout runs no faster than real time (for watching live).
        progress: called with the simulated seconds after each policy step.
        forces: called with the arena and both fighters' bodies (1, 2) before each policy
            step; the forces and torques (1, nbody, 6) it returns act over the step
            (`ArenaEnv.step`'s ``pushes``): an outside hand, as `benchmarks/matched_assist.py`
            measures one.
    """
    if not seconds > 0:
        raise ValueError(f"seconds must be positive, got {seconds!r}")
    config = env_config(opponent)
    slot = opponent.agent
    (mine, theirs), bones, guards = fighters(opponent, partner)
    env = ArenaEnv(config, np.random.default_rng(0), (bones[0], bones[1]))
    start_pose = standing_start(env, guards)
    steps = max(1, round(seconds * config.policy_hz))
    renderer = writer = None
    if video is not None:
        renderer, writer = open_video(env.model, video, size, config.policy_hz)
    falls, unstable, damage = [0, 0], 0, np.zeros(2)
    spent = {"policy": 0.0, "physics": 0.0, "render": 0.0}
    frames = 0
    begin = time.perf_counter()

    def start() -> tuple[np.ndarray, BodyState]:
        obs = env.reset([0], start_pose)
        bodies = env.body_states(np.zeros(1, dtype=int))
        mine.reset(seen(obs, bodies, slot))
        theirs.reset(seen(obs, bodies, 1 - slot))
        return obs, bodies

    try:
        obs, bodies = start()
        for step in range(steps):
            tick = time.perf_counter()
            actions = np.empty((1, 2, NUM_ACTUATED))
            actions[0, slot] = mine.act(seen(obs, bodies, slot))[0]
            actions[0, 1 - slot] = theirs.act(seen(obs, bodies, 1 - slot))[0]
            spent["policy"] += time.perf_counter() - tick
            tick = time.perf_counter()
            result = env.step(actions, pushes=None if forces is None else forces(env, bodies))
            spent["physics"] += time.perf_counter() - tick
            damage += result.damage[0, [slot, 1 - slot]]
            if renderer is not None:
                tick = time.perf_counter()
                render_frame(renderer, writer, env.datas[0])
                frames += 1
                spent["render"] += time.perf_counter() - tick
            obs, bodies = result.observation, result.body
            if result.done[0]:
                fell = result.fell[0]
                falls[0] += int(fell[slot])
                falls[1] += int(fell[1 - slot])
                unstable += int(result.unstable[0])
                obs, bodies = start()
            if progress is not None:
                progress((step + 1) / config.policy_hz)
            if pace:
                ahead = (step + 1) / config.policy_hz - (time.perf_counter() - begin)
                if ahead > 0:
                    time.sleep(ahead)
    finally:
        wall = time.perf_counter() - begin
        env.close()
        if writer is not None:
            writer.close()
        if renderer is not None:
            renderer.close()
    return SparResult(
        simulated_s=steps / config.policy_hz,
        wall_s=wall,
        policy_steps=steps,
        falls=(falls[0], falls[1]),
        unstable=unstable,
        damage_received_n=(float(damage[0]), float(damage[1])),
        frames_rendered=frames,
        video=None if video is None else str(video),
        timings_s=spent,
    )
