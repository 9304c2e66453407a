"""Sparring: an exported opponent against a second fighter in MuJoCo, with onnxruntime only.

`spar` steps one arena of the training environment (`tasks.train.env.ArenaEnv`, the same
physics, observations and fall rule the policy was trained with, read from the opponent's
manifest) with the opponent in its own slot and the partner in the other. Both start standing
at the arena's rest pose, 1.2 m apart and facing each other; a fall (or a blown-up simulation)
restarts the bout from there and is counted. No torch is imported on this path, so an engine
with numpy, MuJoCo and onnxruntime can run it.

Partners (`Partner`): another opponent folder (e.g. the opponent's trained partner,
`ringside export --agent opponent`), or "still", a boxer that holds its rest pose (zero
actions: every PD target at the standing pose), the simplest scripted boxer.

Offscreen rendering uses MuJoCo's renderer through EGL (`MUJOCO_GL=egl`, which `ringside` sets
before MuJoCo is imported; Mesa's software EGL on a machine without a GPU), from the arena's
"side" camera, into an H.264 MP4 (`tasks.pose.overlay.H264Writer`) that browsers play.
`render_bout` renders a recorded bout (the arena's qpos per frame) the same way; the evaluate
stage uses it for its bout video.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from models.humanoid.kinematics import NQ, NUM_ACTUATED, NV
from tasks.evaluate.opponent import Opponent
from tasks.train.env import ArenaEnv, EnvConfig, ReferenceMotions

STILL = "still"


@dataclass(frozen=True)
class Partner:
    """The second fighter: an opponent folder's policy, or None for the still boxer."""

    opponent: Opponent | None = None

    @property
    def name(self) -> str:
        return STILL if self.opponent is None else str(self.opponent.folder)

    def act(self, observation: np.ndarray) -> np.ndarray:
        if self.opponent is None:
            return np.zeros((len(observation), NUM_ACTUATED))
        return self.opponent.act(observation)


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


def _standing(env: ArenaEnv) -> ReferenceMotions:
    q = env.model.qpos0
    zero = np.zeros((1, NV))
    return ReferenceMotions(q[None, :NQ], zero, q[None, NQ:], zero)


def spar(
    opponent: Opponent,
    partner: Partner,
    *,
    seconds: float = 60.0,
    video: Path | None = None,
    size: tuple[int, int] = (640, 360),
    pace: bool = False,
    progress: Callable[[float], None] | None = None,
) -> SparResult:
    """Run a bout of `seconds` simulated seconds; see the module docstring.

    Args:
        opponent: the exported fighter, in its own slot (its manifest's agent).
        partner: the fighter in the other slot.
        seconds: simulated length of the bout.
        video: an MP4 to render the bout to (30 frames per simulated second), or None.
        size: the video's width and height in pixels.
        pace: sleep so that the bout runs no faster than real time (for watching live).
        progress: called with the simulated seconds after each policy step.
    """
    if not seconds > 0:
        raise ValueError(f"seconds must be positive, got {seconds!r}")
    config = env_config(opponent)
    slot = opponent.agent
    bones = list(opponent.bones)
    if partner.opponent is not None:
        bones[1 - slot] = partner.opponent.bones[partner.opponent.agent]
    env = ArenaEnv(config, np.random.default_rng(0), (bones[0], bones[1]))
    start_pose = _standing(env)
    steps = max(1, round(seconds * config.policy_hz))
    renderer = writer = None
    if video is not None:
        renderer, writer = open_video(env.model, video, size, config.policy_hz)
    falls, unstable, damage = [0, 0], 0, np.zeros(2)
    spent = {"policy": 0.0, "physics": 0.0, "render": 0.0}
    frames = 0
    begin = time.perf_counter()
    try:
        obs = env.reset([0], start_pose)
        for step in range(steps):
            tick = time.perf_counter()
            actions = np.empty((1, 2, NUM_ACTUATED))
            actions[0, slot] = opponent.act(obs[:, slot])[0]
            actions[0, 1 - slot] = partner.act(obs[:, 1 - slot])[0]
            spent["policy"] += time.perf_counter() - tick
            tick = time.perf_counter()
            result = env.step(actions)
            spent["physics"] += time.perf_counter() - tick
            damage += result.damage[0, [slot, 1 - slot]]
            if renderer is not None:
                tick = time.perf_counter()
                render_frame(renderer, writer, env.datas[0])
                frames += 1
                spent["render"] += time.perf_counter() - tick
            obs = result.observation
            if result.done[0]:
                fell = result.fell[0]
                falls[0] += int(fell[slot])
                falls[1] += int(fell[1 - slot])
                unstable += int(result.unstable[0])
                obs = env.reset([0], start_pose)
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


def open_video(model, path: Path, size: tuple[int, int], fps: float):
    """An offscreen renderer of arena ``model`` and an H.264 writer for ``path`` (close both).

    Turns the model's shadows off and widens its offscreen framebuffer to ``size`` (w, h).
    """
    import mujoco

    from tasks.pose.overlay import H264Writer

    if os.environ.get("MUJOCO_GL", "").lower() not in ("egl", "osmesa"):
        raise RuntimeError(
            "rendering without a screen needs MUJOCO_GL=egl (or osmesa) set before MuJoCo is "
            f"imported; it is {os.environ.get('MUJOCO_GL')!r}"
        )

    width, height = size
    # Shadows cost 90 % of a frame in Mesa's software EGL (measured at 640 x 360: 584 ms with,
    # 58 ms without); the video is for reviewing moves, not lighting.
    model.vis.quality.shadowsize = 0
    # The offscreen framebuffer must hold the frame (MuJoCo's default is 640 x 480).
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
    model.vis.global_.offheight = max(model.vis.global_.offheight, height)
    renderer = mujoco.Renderer(model, height, width)
    path.parent.mkdir(parents=True, exist_ok=True)
    return renderer, H264Writer(path, (width, height), fps)


def render_frame(renderer, writer, data) -> None:
    """One frame of the arena in ``data`` from its "side" camera, appended to the video."""
    renderer.update_scene(data, camera="side")
    writer.write(renderer.render()[:, :, ::-1])


def render_bout(
    model,
    qpos: np.ndarray,
    path: Path,
    *,
    size: tuple[int, int] = (640, 360),
    fps: float = 30.0,
) -> int:
    """Render a recorded bout, the arena's qpos (T, nq) frame by frame, to an H.264 MP4 at
    ``path``, as `spar` renders a live one; returns the frames written."""
    import mujoco

    q = np.asarray(qpos, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != model.nq or len(q) == 0 or not np.isfinite(q).all():
        raise ValueError(f"qpos must be finite with shape (T >= 1, {model.nq}), got {q.shape}")
    data = mujoco.MjData(model)
    renderer, writer = open_video(model, Path(path), size, fps)
    try:
        for frame in q:
            data.qpos[:] = frame
            mujoco.mj_forward(model, data)
            render_frame(renderer, writer, data)
    finally:
        writer.close()
        renderer.close()
    return len(q)
