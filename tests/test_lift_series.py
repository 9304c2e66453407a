"""The lift's cleanup series on hand-built motions, and its review video of two humanoids."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import read_video

from models.humanoid.boxer import BoneLengths, single_scene_mjcf
from models.humanoid.motion import RATE, FighterMotion
from tasks.lift.series import cleanup_series, fighter_distance
from tasks.media import follow_fighters, render_lift

BONES = BoneLengths()
STANDING = mujoco.MjModel.from_xml_string(single_scene_mjcf(BONES)).qpos0.copy()


def standing(steps: int, *, at=(0.0, 0.0), turn: float = 0.0, keep=None) -> FighterMotion:
    """A boxer standing at its rest pose (soles on the floor) at ``at``, facing ``turn``
    radians from +x, at the steps of ``keep`` (all of 0..steps-1 by default)."""
    step = np.arange(steps) if keep is None else np.asarray(keep)
    qpos = np.repeat(STANDING[None], len(step), axis=0)
    qpos[:, :2] = at
    qpos[:, 3:7] = [np.cos(turn / 2), 0.0, 0.0, np.sin(turn / 2)]
    return FighterMotion(
        step=step,
        qpos=qpos,
        qvel=np.zeros((len(step), 34)),
        joints=np.zeros((len(step), 33, 3)),
        contacts=np.zeros((len(step), 2), bool),
        bones=BONES,
    )


def with_(motion: FighterMotion, **changes) -> FighterMotion:
    fields = {name: getattr(motion, name) for name in FighterMotion.__dataclass_fields__}
    return FighterMotion(**{**fields, **changes})


def test_a_foot_sliding_in_contact_skates_at_its_speed():
    steps, speed = 12, 0.45  # m/s along x
    motion = standing(steps)
    qpos = motion.qpos.copy()
    qpos[:, 0] = speed * np.arange(steps) / RATE
    contacts = np.zeros((steps, 2), bool)
    contacts[2:9, 0] = True  # the left foot is down over steps 2..8, the right never
    series = cleanup_series({"adversary": with_(motion, qpos=qpos, contacts=contacts)})
    slide = series.fighters["adversary"].contact_slide_m_s
    assert slide.shape == (steps, 2)
    # Measured from the step before, while the foot is down at both.
    np.testing.assert_allclose(slide[3:9, 0], speed, rtol=1e-9)
    assert np.isnan(slide[:3, 0]).all() and np.isnan(slide[9:, 0]).all()
    assert np.isnan(slide[:, 1]).all()
    # Standing on the floor: nothing sinks in. One fighter: no distance.
    np.testing.assert_allclose(series.fighters["adversary"].floor_penetration_m, 0.0, atol=1e-9)
    assert np.isnan(series.fighter_distance_m).all()
    np.testing.assert_allclose(series.time_s, np.arange(steps) / RATE)


def test_a_body_pushed_into_the_floor_penetrates_by_that_depth():
    steps = 6
    depth = np.array([0.0, 0.01, 0.035, 0.2, 0.0, 0.05])
    motion = standing(steps)
    qpos = motion.qpos.copy()
    qpos[:, 2] -= depth
    series = cleanup_series({"opponent": with_(motion, qpos=qpos)})
    np.testing.assert_allclose(series.fighters["opponent"].floor_penetration_m, depth, atol=1e-9)
    # Lifted clear of the floor, it does not penetrate at all (not a negative depth).
    qpos[:, 2] += 0.3
    series = cleanup_series({"opponent": with_(motion, qpos=qpos)})
    assert (series.fighters["opponent"].floor_penetration_m == 0).all()


def test_distance_between_pelvises_and_missing_steps():
    steps = 10
    adversary = standing(steps, at=(1.0, 2.0))
    # The opponent is lost at steps 4..5 and after step 7.
    opponent = standing(steps, at=(4.0, 6.0), turn=np.pi, keep=[0, 1, 2, 3, 6, 7])
    contacts = np.ones((6, 2), bool)
    series = cleanup_series(
        {"adversary": adversary, "opponent": with_(opponent, contacts=contacts)}
    )
    distance = series.fighter_distance_m
    assert distance.shape == (steps,)
    np.testing.assert_allclose(distance[[0, 1, 2, 3, 6, 7]], 5.0)
    assert np.isnan(distance[[4, 5, 8, 9]]).all()
    mine = series.fighters["opponent"]
    assert np.isnan(mine.floor_penetration_m[[4, 5, 8, 9]]).all()
    # No slide is measured across the gap, or into the first step back.
    np.testing.assert_allclose(mine.contact_slide_m_s[[1, 2, 3, 7]], 0.0, atol=1e-9)
    assert np.isnan(mine.contact_slide_m_s[[0, 4, 5, 6, 8, 9]]).all()
    np.testing.assert_allclose(
        fighter_distance(np.array([[0.0, 0.0, 1.0]]), np.array([[3.0, 4.0, 0.0]])), [5.0]
    )


def test_the_camera_frames_both_fighters_from_the_side():
    a = np.column_stack([np.linspace(0, 1, 30), np.full(30, 5.0)])
    b = a + [0.0, 2.0]  # b stands 2 m along +y from a
    b[10:20] = np.nan
    framing = follow_fighters(a, b)
    # Looking along -x puts +y (a to b) on the picture's right.
    assert framing.azimuth_deg == pytest.approx(180.0)
    # Where b is missing the camera keeps to a's side of the midpoint, smoothly.
    assert np.isfinite(framing.lookat).all() and framing.lookat.shape == (30, 3)
    np.testing.assert_allclose(framing.lookat[0, :2], [0.0, 6.0], atol=0.05)
    assert 3.0 <= framing.distance_m < 6.0


def colour_pixels(frame: np.ndarray) -> tuple[int, int]:
    """(red, blue) pixel counts of a BGR frame: the adversary's and the opponent's trunks and
    gloves (the skin, floor and sky are neither)."""
    b, g, r = (frame[..., k].astype(int) for k in range(3))
    red = (r > 120) & (r > 2 * g) & (r > 2 * b)
    blue = (b > 120) & (b > 2 * g) & (b > 2 * r)
    return int(red.sum()), int(blue.sum())


def test_video_shows_both_humanoids_and_hides_a_missing_one(tmp_path: Path):
    steps = 12
    # Far from the arena's origin, as the footage places fighters.
    adversary = standing(steps, at=(7.0, -3.0))
    opponent = standing(steps, at=(8.3, -3.0), turn=np.pi, keep=[0, 1, 2, 3, 4, 5])
    path = tmp_path / "lift.mp4"
    written = render_lift({"adversary": adversary, "opponent": opponent}, path)
    fourcc, frames = read_video(path)
    assert written == steps and len(frames) == steps and fourcc in ("avc1", "h264")
    assert frames[0].shape == (360, 640, 3)
    red, blue = colour_pixels(frames[2])
    assert red > 200 and blue > 200
    # The adversary stands on the left of the picture, the opponent on the right.
    columns = np.flatnonzero(frames[2][..., 2].astype(int) > 2 * frames[2][..., 1] + 40)
    assert np.median(columns % 640) < 320
    red, blue = colour_pixels(frames[9])  # the opponent is gone
    assert red > 200 and blue == 0
    # A video with one fighter only renders too.
    render_lift({"opponent": opponent}, path)
    _, frames = read_video(path)
    assert len(frames) == 6 and colour_pixels(frames[3])[1] > 200
    with pytest.raises(ValueError, match="fighters must be keyed by"):
        render_lift({"referee": adversary}, path)
