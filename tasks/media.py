"""Videos the stages write: H.264 MP4 that browsers play (`H264Writer`; OpenCV's wheel writes
only MPEG-4 Part 2, which browsers do not, so the video goes through the H.264 encoder of the
ffmpeg that ``imageio-ffmpeg`` ships), and MuJoCo humanoids rendered offscreen into one.

`render_lift` is the lift stage's review video: both fighters' cleaned motion, each on a humanoid
of its own bones, in the training arena (`models.arena.mjcf`: the adversary is agent 0, red;
the opponent agent 1, blue), seen from the side by a camera that follows them. `render_bout`
renders a recorded arena motion from the arena's fixed "side" camera (the evaluate stage's bout
video; `tasks.opponent.spar` renders live bouts with `open_video` and `render_frame`).

Rendering uses MuJoCo's renderer through EGL (`MUJOCO_GL=egl`, which `ringside` sets before
MuJoCo is imported; Mesa's software EGL on a machine without a GPU).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import cv2
import imageio_ffmpeg
import mujoco
import numpy as np

from models.arena.mjcf import arena_mjcf
from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import NQ
from models.humanoid.motion import RATE, FighterMotion, gaussian_smooth, grid_steps
from tasks.roles import ROLES

VIDEO_SIZE = (640, 360)
# How far a fighter missing at a step is moved away, metres: out of view, and out of the light.
PARKED_M = 1000.0


class H264Writer:
    """Writes BGR frames of one size to an H.264 MP4 that browsers play (yuv420p, faststart)."""

    def __init__(self, path: Path, size: tuple[int, int], fps: float):
        self.size = size
        self._writer = imageio_ffmpeg.write_frames(
            str(path),
            size,
            fps=fps,
            codec="libx264",
            pix_fmt_in="bgr24",
            quality=None,
            macro_block_size=2,
            output_params=[
                "-pix_fmt",
                "yuv420p",
                "-preset",
                "veryfast",
                "-crf",
                "26",
                "-movflags",
                "+faststart",
            ],
            # ffmpeg shares our terminal: at "error" a command stopped mid-frame (Ctrl-C) printed
            # ffmpeg's complaint about the cut frame above its one line. A fatal error still shows.
            ffmpeg_log_level="fatal",
        )
        self._writer.send(None)

    def write(self, frame: np.ndarray) -> None:
        if (frame.shape[1], frame.shape[0]) != self.size:
            frame = cv2.resize(frame, self.size, interpolation=cv2.INTER_AREA)
        self._writer.send(np.ascontiguousarray(frame))

    def close(self) -> None:
        self._writer.close()

    def __enter__(self) -> H264Writer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_video(model: mujoco.MjModel, path: Path, size: tuple[int, int], fps: float):
    """An offscreen renderer of ``model`` and an H.264 writer for ``path`` (close both).

    Turns the model's shadows off and widens its offscreen framebuffer to ``size`` (w, h).
    """
    if os.environ.get("MUJOCO_GL", "").lower() not in ("egl", "osmesa"):
        raise RuntimeError(
            "rendering without a screen needs MUJOCO_GL=egl (or osmesa) set before MuJoCo is "
            f"imported; it is {os.environ.get('MUJOCO_GL')!r}"
        )

    width, height = size
    # Shadows cost 90 % of a frame in Mesa's software EGL (measured at 640 x 360: 584 ms with,
    # 58 ms without); the video is for reviewing moves, not lighting.
    model.vis.quality.shadowsize = 0
    # So does 4x multisampling, half of what remains (640 x 360: 45 ms a frame with it, 20 ms
    # without); edges show their pixels, which a review video can afford.
    model.vis.quality.offsamples = 0
    # The offscreen framebuffer must hold the frame (MuJoCo's default is 640 x 480).
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
    model.vis.global_.offheight = max(model.vis.global_.offheight, height)
    renderer = mujoco.Renderer(model, height, width)
    path.parent.mkdir(parents=True, exist_ok=True)
    return renderer, H264Writer(path, (width, height), fps)


def render_frame(renderer, writer, data, camera: str | mujoco.MjvCamera = "side") -> None:
    """One frame of the scene in ``data`` from ``camera`` (a model camera's name, or a free
    `mujoco.MjvCamera`), appended to the video."""
    renderer.update_scene(data, camera=camera)
    writer.write(renderer.render()[:, :, ::-1])


def render_bout(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    path: Path,
    *,
    size: tuple[int, int] = VIDEO_SIZE,
    fps: float = 30.0,
) -> int:
    """Render a recorded bout, the arena's qpos (T, nq) frame by frame, to an H.264 MP4 at
    ``path`` from the arena's "side" camera; returns the frames written."""
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


@dataclass(frozen=True, eq=False)
class Framing:
    """Where a following camera looks: a point per step, from one side, at one distance.

    Attributes:
        lookat: (S, 3) the point the camera looks at, per step.
        azimuth_deg: the camera's fixed heading (MuJoCo's free-camera azimuth).
        distance_m: from the camera to ``lookat``.
    """

    lookat: np.ndarray
    azimuth_deg: float
    distance_m: float


def follow_fighters(
    pelvis_a: np.ndarray,
    pelvis_b: np.ndarray,
    *,
    fovy_deg: float = 45.0,
    aspect: float = 16 / 9,
    rate: float = RATE,
) -> Framing:
    """A side view of two fighters that keeps both in the picture.

    The camera looks across the line from fighter a to fighter b, on average over the steps
    both are there, so a stands on the left of the picture and b on the right; it is kept
    fixed in direction (a turning camera is hard to follow) and distance, so that 95 % of the
    steps' separations fit across the picture, and it follows the fighters' midpoint, smoothed
    over a quarter second so the picture does not shake with the lift's noise.

    Args:
        pelvis_a: (S, 2) fighter a's pelvis x, y per step; NaN where it is missing.
        pelvis_b: (S, 2) the same for fighter b.
        fovy_deg: the camera's vertical field of view.
        aspect: width / height of the picture.
        rate: steps per second.
    """
    a, b = np.asarray(pelvis_a, float), np.asarray(pelvis_b, float)
    steps = len(a)
    has_a, has_b = np.isfinite(a).all(1), np.isfinite(b).all(1)
    # The midpoint where both are there, else the one that is.
    centre = np.where(has_b[:, None], np.where(has_a[:, None], (a + b) / 2, b), a)
    seen = has_a | has_b
    if not seen.any():
        raise ValueError("pelvis_a and pelvis_b must be finite at some step")
    # Steps where neither fighter is there keep the camera moving straight between the others.
    at = np.arange(steps)
    centre = np.stack([np.interp(at, at[seen], centre[seen, k]) for k in range(2)], axis=1)
    centre = gaussian_smooth(centre, 0.25 * rate)
    both = has_a & has_b
    gap = b[both] - a[both]
    direction = gap.mean(axis=0) if both.any() else np.array([1.0, 0.0])
    if np.linalg.norm(direction) < 1e-6:
        direction = np.array([1.0, 0.0])
    direction /= np.linalg.norm(direction)
    # Looking along f = z x d puts d (a to b) on the picture's right: right = f x z.
    forward = np.array([-direction[1], direction[0]])
    spread = float(np.percentile(np.linalg.norm(gap, axis=1), 95)) if both.any() else 0.0
    # Half the picture's width must hold half the spread plus a fighter's reach (0.8 m).
    half_width = math.tan(math.radians(fovy_deg) / 2) * aspect
    distance = max(3.0, (spread / 2 + 0.8) / half_width)
    # Look at the fighters' chests, roughly: heads and feet both stay in the picture.
    lookat = np.column_stack([centre, np.full(steps, 1.0)])
    return Framing(lookat, math.degrees(math.atan2(forward[1], forward[0])), distance)


def render_lift(
    fighters: Mapping[str, FighterMotion],
    path: Path,
    *,
    size: tuple[int, int] = VIDEO_SIZE,
    fps: float = RATE,
) -> int:
    """Both fighters' humanoids, one frame per step of their 30 Hz grid, to an H.264 MP4.

    A fighter missing at a step (no row there, or no motion at all) is moved far out of view.

    Args:
        fighters: role ("adversary", "opponent") -> its motion and bones.
        path: the MP4 to write.
        size: width and height in pixels.
        fps: frames per second of the video (the grid's rate plays it in real time).

    Returns:
        The frames written: one past the last step of either fighter.
    """
    unknown = set(fighters) - set(ROLES)
    if unknown:
        raise ValueError(f"fighters must be keyed by {ROLES}, got {sorted(unknown)}")
    steps = grid_steps(fighters)
    if steps == 0:
        raise ValueError("fighters must hold at least one lifted step")
    bones = tuple(fighters[r].bones if r in fighters else BoneLengths() for r in ROLES)
    model = mujoco.MjModel.from_xml_string(arena_mjcf(bones))
    qpos = np.repeat(model.qpos0[None], steps, axis=0)
    pelvis = []
    for agent, role in enumerate(ROLES):
        mine = slice(agent * NQ, (agent + 1) * NQ)
        q = np.full((steps, NQ), np.nan)
        if role in fighters:
            q = fighters[role].on_grid(fighters[role].qpos, steps)
        missing = ~np.isfinite(q).all(axis=1)
        parked = model.qpos0[mine].copy()
        parked[0] += PARKED_M
        qpos[:, mine] = np.where(missing[:, None], parked, q)
        pelvis.append(q[:, :2])  # NaN where missing
    framing = follow_fighters(
        *pelvis,
        fovy_deg=float(model.vis.global_.fovy),
        aspect=size[0] / size[1],
        rate=fps,
    )
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.azimuth = framing.azimuth_deg
    camera.elevation = -10.0
    camera.distance = framing.distance_m
    light = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_LIGHT, "light")
    data = mujoco.MjData(model)
    renderer, writer = open_video(model, Path(path), size, fps)
    try:
        for step in range(steps):
            data.qpos[:] = qpos[step]
            # The arena's spot light hangs over its origin; the fighters stand where the
            # footage put them, so it goes with them.
            model.light_pos[light, :2] = framing.lookat[step, :2]
            mujoco.mj_forward(model, data)
            camera.lookat[:] = framing.lookat[step]
            render_frame(renderer, writer, data, camera)
    finally:
        writer.close()
        renderer.close()
    return steps
