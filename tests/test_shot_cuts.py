"""A hard cut: the sample cut to its mirror image at frame 48 (issue 33, items 3 and 4).

Each shot is its own camera and its own world, so nothing may be smoothed, differentiated or
carried across the cut: each side must come out of the lift as it does from a video of that
side alone, and the steps around the cut must be judged by the gates like any other.
"""

from __future__ import annotations

import io
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import cv2
import mujoco
import numpy as np
import pytest
from conftest import process_argv, query, read_video
from test_lift_series import standing, with_

from flows.cli import main
from models.humanoid.boxer import BoneLengths, single_scene_mjcf
from models.humanoid.motion import RATE
from models.pose.types import BLAZEPOSE_33
from tasks.lift.gates import GateConfig
from tasks.lift.resample import resample
from tasks.lift.series import cleanup_series
from tasks.pose.config import SMOOTHER_NAMES, RefineConfig
from tasks.pose.refine import flip_groups, flip_permutation, jitter_px, refine

# The frame the mirror image starts at: a multiple of pose.detect_every (3), so that the
# second shot's frames are searched by the detector at the frames they are searched at in a
# video of their own (the detector runs on frame indices, not shot frames: cut at 50, the two
# second shots are searched at different frames and their joints differ by ~10 px).
CUT = 48
FPS = 60.0  # the sample's own rate
NEAR = 3  # steps either side of the cut that are looked at


@pytest.fixture(scope="module")
def cut_runs(tmp_path_factory, sample_video: Path) -> dict[str, Path]:
    """The data directories of three videos taken to the lift, without colour or pick: the
    cut video ('cut'), its first shot alone ('before') and its second alone ('after')."""
    _, frames = read_video(sample_video)
    mirrored = [cv2.flip(f, 1) for f in frames[CUT:]]
    videos = {"cut": frames[:CUT] + mirrored, "before": frames[:CUT], "after": mirrored}
    root = tmp_path_factory.mktemp("shot_cuts")
    runs = {}
    for name, shown in videos.items():
        video = lossless_video(root / f"{name}.mp4", shown, fps=FPS)
        data = root / name
        out, err = io.StringIO(), io.StringIO()
        with redirect_stdout(out), redirect_stderr(err):
            code = main(process_argv(data, video, until="lift"))
        assert code == 0, f"{name}: {err.getvalue()[-2000:]}"
        runs[name] = data
    return runs


def lossless_video(path: Path, frames: list[np.ndarray], fps: float) -> Path:
    """BGR frames as lossless H.264 (4:4:4): a frame decodes to the same pixels whatever comes
    before it. A lossy codec codes the first frame after a cut unlike the first frame of a
    video (mp4v: 1.3 grey levels apart on average, the first frame's joints 2.7 px), which
    would set the two sides' lifts apart whatever the lift does."""
    import imageio_ffmpeg

    h, w = frames[0].shape[:2]
    writer = imageio_ffmpeg.write_frames(
        str(path),
        (w, h),
        pix_fmt_in="bgr24",
        pix_fmt_out="yuv444p",
        fps=fps,
        codec="libx264",
        quality=None,
        macro_block_size=1,
        # Lossless at any preset; ultrafast wrote the sample's 100 frames in 1.5 s, not 7.6.
        output_params=["-qp", "0", "-preset", "ultrafast"],
    )
    writer.send(None)
    for frame in frames:
        writer.send(np.ascontiguousarray(frame))
    writer.close()
    return path


def pelvis_depths(data: Path) -> dict[str, dict[int, tuple[float, np.ndarray]]]:
    """Per role, per 30 Hz step: the pelvis's depth (m, along its shot camera's axis) and its
    image position (px, through that camera), from the stored lift."""
    cameras = {
        shot: (np.reshape(R, (3, 3)), np.asarray(t), np.reshape(K, (3, 3)))
        for shot, K, R, t in query(data, "SELECT shot, K, R, t FROM lift_cameras")
    }
    starts = sorted(
        (start, shot) for shot, start in query(data, "SELECT shot, start_frame FROM ingest_shots")
    )
    found: dict[str, dict[int, tuple[float, np.ndarray]]] = {}
    for role, step, qpos in query(data, "SELECT role, step, qpos FROM lift_motion"):
        frame = step / RATE * FPS
        shot = [s for start, s in starts if start <= frame + 1e-6][-1]
        R, t, K = cameras[shot]
        camera = R @ np.asarray(qpos[:3]) + t
        pixel = (K @ camera)[:2] / camera[2]
        found.setdefault(role, {})[int(step)] = (float(camera[2]), pixel)
    return found


def root_speeds(data: Path) -> dict[str, dict[int, float]]:
    """Per role, per step: the stored pelvis speed (m/s, |qvel[:3]|), what the dataset keeps."""
    speeds: dict[str, dict[int, float]] = {}
    for role, step, qvel in query(data, "SELECT role, step, qvel FROM lift_motion"):
        speeds.setdefault(role, {})[int(step)] = float(np.linalg.norm(qvel[:3]))
    return speeds


def same_fighter(cut: dict, alone: dict, steps: range) -> dict[str, str]:
    """For each role of the cut video, the role of the side-alone video on the same person:
    the one whose pelvis is drawn nearest in the image over ``steps`` (the two videos show the
    same pixels, so the same person is within a few pixels; the roles may differ, as a
    second shot's roles come from the first shot's appearance)."""
    matched = {}
    for role, mine in cut.items():
        gaps = {}
        for other, theirs in alone.items():
            both = [s for s in steps if s in mine and s in theirs]
            if both:
                gaps[other] = np.median([np.linalg.norm(mine[s][1] - theirs[s][1]) for s in both])
        if gaps:
            matched[role] = min(gaps, key=gaps.get)
    return matched


def around_the_cut(runs: dict[str, Path]) -> tuple[dict, dict]:
    """What the cut does to the lift of ``runs`` (`cut_runs`): per role, the pelvis speed
    (m/s) at each step within ``NEAR`` steps of the cut; and per (side, role), the pelvis
    depth (m) at each step of that side, in the cut video and from that side alone."""
    cut_step = round(CUT / FPS * RATE)
    near = range(cut_step - NEAR, cut_step + NEAR)
    speeds = {
        role: {s: v for s, v in mine.items() if s in near}
        for role, mine in root_speeds(runs["cut"]).items()
    }
    depths = pelvis_depths(runs["cut"])
    sides = {
        "before": (range(cut_step), 0),
        "after": (range(cut_step, 2 * cut_step + 100), cut_step),
    }
    compared = {}
    for side, (steps, shift) in sides.items():
        alone = {
            role: {s + shift: v for s, v in mine.items()}
            for role, mine in pelvis_depths(runs[side]).items()
        }
        for role, other in same_fighter(depths, alone, steps).items():
            compared[(side, role)] = {
                s: (depths[role][s][0], alone[other][s][0])
                for s in steps
                if s in depths[role] and s in alone[other]
            }
    return speeds, compared


def test_a_hard_cut_is_lifted_as_two_shots(cut_runs: dict[str, Path]):
    """Within 3 steps of the cut no pelvis moves faster than the gate's limit, and each side's
    pelvis depth is that of the same frames lifted from a video of that side alone, within
    5 cm. Before, the pose stage smoothed the keypoints across the cut and the lift took
    velocities across it: the opponent moved at 18.8 m/s at the cut (the central difference
    between two shots' worlds), the adversary's depth was off by up to 23 cm before it and
    34 cm after it (pulled towards the other shot's), and he moved at 5.8 m/s."""
    limit = GateConfig().max_root_speed_m_s
    speeds, compared = around_the_cut(cut_runs)
    fast = {r: {s: round(v, 2) for s, v in m.items() if v > limit} for r, m in speeds.items()}
    assert len(speeds) == 2 and all(len(m) == 2 * NEAR for m in speeds.values()), speeds
    assert not any(fast.values()), f"steps faster than {limit} m/s by the cut: {fast}"
    assert len(compared) == 4, f"each side's two fighters in both videos: {sorted(compared)}"
    off = {k: max(abs(a - b) for a, b in v.values()) for k, v in compared.items()}
    assert max(off.values()) <= 0.05, f"largest depth differences (m): {off}"


def test_a_guess_carried_to_the_next_shot_stays_a_guess(cut_runs: dict[str, Path]):
    """Without a colour or pick, the adversary of the cut video is a guess in both shots: the
    second shot's roles follow the first shot's appearance, which was itself guessed."""
    metrics = dict(
        query(cut_runs["cut"], "SELECT name, value FROM stage_metrics WHERE stage = 'pose'")
    )
    ((notes,),) = query(cut_runs["cut"], "SELECT notes FROM stage_outputs WHERE stage = 'pose'")
    assert metrics["adversary_guessed"] == 1
    assert any("the adversary is a guess" in note for note in notes), notes


def _walker(frames: int, x0: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(frames, 33, 2) keypoints of a body drifting sideways from ``x0`` px with 2 px noise,
    and (frames, 33) confidences."""
    pose = rng.uniform(-60, 60, (33, 2)) + [x0, 500.0]
    drift = np.arange(frames)[:, None, None] * [3.0, 0.0]
    keypoints = pose + drift + rng.normal(0, 2.0, (frames, 33, 2))
    return keypoints, rng.uniform(0.6, 1.0, (frames, 33))


@pytest.mark.parametrize("smoother", SMOOTHER_NAMES)
def test_each_shot_is_refined_as_if_alone(smoother: str):
    """Keypoints cut from one place in the picture to another (and missing for the two frames
    either side of the cut): refined with the cut, each shot is what refining it alone gives,
    so no smoother, gap fill or flip reaches across; refined without, the frames by the cut
    are pulled towards the other shot."""
    rng = np.random.default_rng(0)
    (a, ca), (b, cb) = _walker(40, 300.0, rng), _walker(30, 900.0, rng)
    a[-2:], b[:2], ca[-2:], cb[:2] = np.nan, np.nan, 0.0, 0.0
    both, conf = np.concatenate([a, b]), np.concatenate([ca, cb])
    config = RefineConfig(smoother=smoother)
    perm = flip_permutation(BLAZEPOSE_33)
    groups = flip_groups(BLAZEPOSE_33)
    cut = refine(both, conf, 60.0, config, perm, groups=groups, cuts=[40])
    alone = [refine(k, c, 60.0, config, perm, groups=groups) for k, c in ((a, ca), (b, cb))]
    np.testing.assert_array_equal(cut.keypoints, np.concatenate([r.keypoints for r in alone]))
    np.testing.assert_array_equal(cut.confidence, np.concatenate([r.confidence for r in alone]))
    assert np.isnan(cut.keypoints[38:42]).all()  # the gap by the cut is not bridged across it
    whole = refine(both, conf, 60.0, config, perm, groups=groups)
    assert np.isfinite(whole.keypoints[38:42]).all()  # as it was: filled from one shot to the next
    assert cut.jitter_before < 10 < jitter_px(np.concatenate([a[:-2], b[2:]]))


def test_no_step_is_resampled_or_differentiated_across_a_cut():
    """A humanoid standing still in each of two shots, 4 m apart in the two shots' worlds,
    at 60 fps (steps on frames) and at 25 fps (steps between frames): with the cut, no step
    lies between the two shots and every velocity is 0; without it, the step by the cut moves
    faster than the gate believes."""
    bones = BoneLengths()
    rest = mujoco.MjModel.from_xml_string(single_scene_mjcf(bones)).qpos0
    for fps, frames, cut in ((60.0, 100, 50), (25.0, 50, 24)):
        qpos = np.repeat(rest[None], frames, axis=0)
        qpos[cut:, 0] += 4.0
        joints, contacts = np.zeros((frames, 33, 3)), np.zeros((frames, 2), bool)
        motion = resample(qpos, joints, contacts, fps=fps, rate=RATE, bones=bones, cuts=[cut])
        np.testing.assert_allclose(motion.qvel, 0.0, atol=1e-9)
        assert set(np.unique(motion.qpos[:, 0]).round(9)) == {rest[0], rest[0] + 4.0}
        last = (frames - 1) / fps * RATE
        expected = [s for s in range(int(last) + 1) if not cut - 1 < s / RATE * fps < cut]
        assert motion.step.tolist() == expected
        crossing = resample(qpos, joints, contacts, fps=fps, rate=RATE, bones=bones)
        assert np.abs(crossing.qvel[:, 0]).max() > GateConfig().max_root_speed_m_s


def test_no_foot_slides_across_a_cut():
    """Both feet down and still in each shot, the body 4 m apart in the two shots' worlds:
    with the cut, no slide is measured at the step it starts; without it, the feet slide at
    4 m per step."""
    motion = standing(20)
    qpos = motion.qpos.copy()
    qpos[10:, 0] += 4.0
    moved = with_(motion, qpos=qpos, contacts=np.ones((20, 2), bool))
    slide = cleanup_series({"adversary": moved}, cuts=[10]).fighters["adversary"]
    assert np.isnan(slide.contact_slide_m_s[10]).all()
    np.testing.assert_allclose(np.delete(slide.contact_slide_m_s, [0, 10], axis=0), 0.0, atol=1e-9)
    crossing = cleanup_series({"adversary": moved}).fighters["adversary"]
    np.testing.assert_allclose(crossing.contact_slide_m_s[10], 4.0 * RATE)
