"""The humanoid stands: every body the sample gives, and the default body, hold the rest pose for
30 s in the training arena, at the rate training uses, with exploration-sized action noise.

Before the measured leg gains, knee lock, contact stiffness and proportional feet
(`models.humanoid.boxer`), the same trials fell in 2-4 s (one of the sample's fighters, whose
heel was measured 1.1 cm behind the ankle, in 1.7 s).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import query

from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import NQ, NV
from models.maaip.demonstrations import facing_reference
from models.maaip.env import ArenaEnv, EnvConfig
from storage.db import connect
from tasks.lift.store import load_motion

NOISE_STD = 0.02
SECONDS = 30.0
TRIALS = 16


def seconds_standing(bones: tuple[BoneLengths, BoneLengths], *, seed: int) -> np.ndarray:
    """(TRIALS,) seconds until either fighter of each arena fell (SECONDS if none did), both
    starting in the rest pose 1.2 m apart and holding it with N(0, NOISE_STD) on every target."""
    config = EnvConfig(num_envs=TRIALS, episode_s=SECONDS)
    rest = np.zeros((1, NQ))
    rest[0, 3] = 1.0  # upright; the reset puts the soles on the floor
    reference = facing_reference(rest, np.zeros((1, NV)))
    rng = np.random.default_rng(seed)
    standing = np.full(TRIALS, SECONDS)
    alive = np.ones(TRIALS, dtype=bool)
    with ArenaEnv(config, rng, bones) as env:
        env.reset(np.arange(TRIALS), reference)
        for step in range(config.max_steps):
            result = env.step(rng.normal(0.0, NOISE_STD, (TRIALS, 2, 28)))
            standing[alive & result.terminated] = (step + 1) / config.policy_hz
            alive &= ~result.terminated
    return standing


def sample_bones(data: Path) -> list[BoneLengths]:
    sql = "SELECT video_id, key FROM stage_outputs WHERE stage = 'lift'"
    (video_id, key), *_ = query(data, sql)
    with connect(data / "ringside.duckdb", read_only=True) as con:
        fighters = load_motion(con, video_id, key)
    return [fighter.bones for fighter in fighters.values()]


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
