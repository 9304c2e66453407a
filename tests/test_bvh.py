"""BVH out: read back by readers we did not write (bvhio from PyPI, Blender's importer), joints
where MuJoCo puts them."""

from __future__ import annotations

import bvhio
import mujoco
import numpy as np
import pytest
from bvh_readers import blender_available, blender_positions, bvhio_positions, fk_positions

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.bvh import bvh_text
from models.humanoid.kinematics import BODY_NAMES
from tasks.evaluate.motion_files import BOUTS, bout_files, bouts_npz

BODIES = {"default": BoneLengths(), "short": BoneLengths().scaled(1.55 / 1.78)}


def random_poses(bones: BoneLengths, frames: int, seed: int) -> tuple[mujoco.MjModel, np.ndarray]:
    """Poses across every joint's whole range, at random places and root orientations."""
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(bones))
    rng = np.random.default_rng(seed)
    qpos = np.tile(model.qpos0, (frames, 1))
    qpos[:, :3] += rng.normal(0.0, 1.0, (frames, 3))
    quat = rng.normal(size=(frames, 4))
    qpos[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    qpos[:, 7:] = rng.uniform(model.jnt_range[1:, 0], model.jnt_range[1:, 1], (frames, 28))
    return model, qpos


@pytest.mark.parametrize("body", BODIES)
def test_an_independent_reader_puts_every_joint_where_mujoco_does(tmp_path, body):
    bones = BODIES[body]
    model, qpos = random_poses(bones, 40, seed=len(body))
    path = tmp_path / "motion.bvh"
    path.write_text(bvh_text(bones, qpos, 30.0))

    parsed = bvhio.readAsBvh(str(path))
    assert parsed.FrameCount == 40
    assert parsed.FrameTime == pytest.approx(1 / 30, abs=1e-7)
    names, positions = bvhio_positions(path)
    assert names == list(BODY_NAMES)
    error = np.abs(positions - fk_positions(model, qpos, names)).max()
    assert error < 1e-5, f"{error * 1000:.3f} mm"


def test_blender_imports_it_with_every_joint_where_mujoco_puts_it(tmp_path):
    if not blender_available():
        pytest.skip("Debian's blender is not installed (apt-get install blender): not compared")
    bones = BODIES["short"]
    model, qpos = random_poses(bones, 30, seed=7)
    path = tmp_path / "motion.bvh"
    path.write_text(bvh_text(bones, qpos, 30.0))
    names, positions = blender_positions(path)
    assert sorted(names) == sorted(BODY_NAMES) and len(positions) == 30
    error = np.abs(positions - fk_positions(model, qpos, names)).max()
    assert error < 1e-5, f"{error * 1000:.3f} mm"  # the issue asks for 1 cm


def test_stored_bouts_become_one_file_per_episode_and_fighter(tmp_path):
    bones = (BODIES["default"], BODIES["short"])
    models, halves = zip(*(random_poses(b, 12, seed=i) for i, b in enumerate(bones)), strict=True)
    qpos = np.full((2, 12, 70), np.nan)
    qpos[:, :, :35], qpos[:, :, 35:] = halves[0], halves[1]
    frames = np.array([12, 5])  # the second episode ended early: NaN after its fifth row

    files = bout_files(bouts_npz(qpos, frames, bones))
    assert sorted(files) == [
        "bout00-adversary.bvh",
        "bout00-opponent.bvh",
        "bout01-adversary.bvh",
        "bout01-opponent.bvh",
    ]
    assert [files[n].frames for n in sorted(files)] == [12, 12, 5, 5]
    path = tmp_path / "bout.bvh"
    path.write_text(files["bout01-opponent.bvh"].text)
    names, positions = bvhio_positions(path)
    expected = fk_positions(models[1], halves[1][:5], names)
    assert np.abs(positions - expected).max() < 1e-5  # stored as float32
    assert BOUTS.endswith(".npz")


@pytest.mark.parametrize(
    ("qpos", "fps", "problem"),
    [
        (np.zeros((0, 35)), 30.0, "shape"),
        (np.zeros((3, 34)), 30.0, "shape"),
        (np.full((3, 35), np.nan), 30.0, "finite"),
        (np.zeros((3, 35)), 0.0, "fps"),
    ],
)
def test_bad_motion_is_refused_by_name(qpos, fps, problem):
    with pytest.raises(ValueError, match=problem):
        bvh_text(BoneLengths(), qpos, fps)
