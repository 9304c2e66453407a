"""The humanoid stands: every body the sample gives, and the default body, hold the rest pose for
30 s in the training arena, at the rate training uses, with exploration-sized action noise.

Before the measured leg gains, knee lock, contact stiffness and proportional feet
(`models.humanoid.boxer`), the same trials fell in 2-4 s (one of the sample's fighters, whose
heel was measured 1.1 cm behind the ankle, in 1.7 s).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import query

from models.arena.env import ArenaEnv
from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.kinematics import HINGE_NAMES, NQ, NV, joint_targets_to_action
from models.humanoid.motion import FighterMotion
from models.humanoid.stance import COM_AHEAD_M, guard_pose
from models.maaip.config import EnvConfig
from models.maaip.demonstrations import ReferenceMotions, facing_reference
from storage.db import connect
from tasks.lift.store import load_motion

NOISE_STD = 0.02
SECONDS = 30.0
TRIALS = 16


def seconds_standing(
    bones: tuple[BoneLengths, BoneLengths], *, seed: int, stance: np.ndarray | None = None
) -> np.ndarray:
    """(TRIALS,) seconds until either fighter of each arena fell (SECONDS if none did), both
    starting in ``stance`` (2, 28) hinges (None: the rest pose) 1.2 m apart and holding it
    with N(0, NOISE_STD) on every target."""
    config = EnvConfig(num_envs=TRIALS, episode_s=SECONDS, standing_share=1.0)
    rest = np.zeros((1, NQ))
    rest[0, 3] = 1.0  # upright; the reset puts the soles on the floor
    pair = facing_reference(rest, np.zeros((1, NV)))
    reference = ReferenceMotions(pair.qpos0, pair.qvel0, pair.qpos1, pair.qvel1, stance=stance)
    held = np.zeros((2, 28)) if stance is None else joint_targets_to_action(stance)
    rng = np.random.default_rng(seed)
    standing = np.full(TRIALS, SECONDS)
    alive = np.ones(TRIALS, dtype=bool)
    with ArenaEnv(config, rng, bones) as env:
        env.reset(np.arange(TRIALS), reference)
        for step in range(config.max_steps):
            result = env.step(held + rng.normal(0.0, NOISE_STD, (TRIALS, 2, 28)))
            standing[alive & result.terminated] = (step + 1) / config.policy_hz
            alive &= ~result.terminated
    return standing


def sample_fighters(data: Path) -> list[FighterMotion]:
    sql = "SELECT video_id, key FROM stage_outputs WHERE stage = 'lift'"
    (video_id, key), *_ = query(data, sql)
    with connect(data / "ringside.duckdb", read_only=True) as con:
        return list(load_motion(con, video_id, key).values())


def sample_bones(data: Path) -> list[BoneLengths]:
    return [fighter.bones for fighter in sample_fighters(data)]


def test_the_default_body_holds_its_rest_pose_for_30_s_with_action_noise() -> None:
    assert EnvConfig().substeps == 4  # the rate training uses: 120 Hz
    standing = seconds_standing((BoneLengths(), BoneLengths()), seed=0)
    assert standing.min() == SECONDS, f"fell after {np.sort(standing)[:4]} s"


def test_every_body_the_sample_gives_holds_its_rest_pose(sample_run: Path) -> None:
    bones = sample_bones(sample_run)
    assert len(bones) == 2
    for body in bones:
        # The feet carry the body whatever the video measured (one heel measured 1.1 cm).
        assert body.heel_back >= 0.035 and body.toe_forward >= 0.12, body
        standing = seconds_standing((body, body), seed=1)
        assert standing.min() == SECONDS, f"{body} fell after {np.sort(standing)[:4]} s"
    standing = seconds_standing((bones[0], bones[1]), seed=2)
    assert standing.min() == SECONDS, f"the sample's pair fell after {np.sort(standing)[:4]} s"


@pytest.mark.parametrize("heel", [0.0705, 0.075, 0.3])
def test_feet_from_proportions_replace_an_implausible_measurement(heel: float) -> None:
    measured = BoneLengths(heel=heel, foot=0.19)
    feet = measured.with_plausible_feet()
    expected = 0.153 * measured.stature
    assert feet.toe_forward + feet.heel_back == pytest.approx(expected, rel=0.01)
    assert feet.heel_back == pytest.approx(0.235 * expected, rel=0.01)
    kept = BoneLengths().with_plausible_feet()
    assert kept.foot == pytest.approx(BoneLengths().foot, abs=5e-4)
    assert kept.heel == pytest.approx(BoneLengths().heel, abs=5e-4)


def test_every_fighter_of_the_sample_holds_its_guard(sample_run: Path) -> None:
    """The guard (its footage's median spine, neck and arms on its median knee bend) stands
    unaided, where holding a frame of the footage, or of DeepMimic's punch, fell in 1-2 s."""
    fighters = sample_fighters(sample_run)
    bones = (fighters[0].bones, fighters[1].bones)
    stance = np.stack([guard_pose(f.bones, f.qpos) for f in fighters])
    assert (stance[:, HINGE_NAMES.index("left_knee")] > 0.2).all()  # bent, as in the footage
    standing = seconds_standing(bones, seed=3, stance=stance)
    assert standing.min() == SECONDS, f"the guards fell after {np.sort(standing)[:4]} s"


def test_the_guard_is_balanced_over_the_ankles_with_flat_feet() -> None:
    bones = BoneLengths()
    frames = np.zeros((5, NQ))
    frames[:, 3] = 1.0
    knee = HINGE_NAMES.index("left_knee")
    for side in ("left", "right"):
        frames[:, 7 + HINGE_NAMES.index(f"{side}_knee")] = [0.2, 0.3, 0.4, 0.5, 0.6]
    frames[:, 7 + HINGE_NAMES.index("right_elbow")] = 1.2
    pose = guard_pose(bones, frames)
    assert pose[knee] == pytest.approx(0.4) and pose[HINGE_NAMES.index("right_knee")] == 0.4
    assert pose[HINGE_NAMES.index("right_elbow")] == pytest.approx(1.2)
    for side in ("left", "right"):
        pitch = [pose[HINGE_NAMES.index(f"{side}_{j}")] for j in ("hip_y", "knee", "ankle_y")]
        assert sum(pitch) == pytest.approx(0.0, abs=1e-12)  # the sole parallel to the pelvis
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(bones))
    data = mujoco.MjData(model)
    data.qpos[3], data.qpos[7:] = 1.0, pose
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    ankles = np.mean([data.xpos[model.body(f"{s}_foot").id, 0] for s in ("left", "right")])
    assert data.subtree_com[1, 0] - ankles == pytest.approx(COM_AHEAD_M, abs=1e-3)
    with pytest.raises(ValueError, match="qpos"):
        guard_pose(bones, np.zeros((0, NQ)))
