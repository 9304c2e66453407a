"""Training as the bout plays: an episode's first match eased in from the standing body
(`MatchConfig.ease_steps`), and a tracker trained in bouts (`train.track.bouts`,
models.tracking.bouts), both fighters standing at rest in their guards where the footage has
them, each tracking what its own matcher picks against the other.

The footage is DeepMimic's walk with its partner 4 m ahead and its punch with the partner 0.7 m
ahead (tests/opponents.py), both fighters on the default bones."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from opponents import TRACK, walk_punch_footage
from training_runs import resumes_exactly

from models.arena.controller import Seen
from models.arena.env import ArenaEnv
from models.arena.starts import geom_bottoms
from models.humanoid.boxer import BoneLengths
from models.humanoid.observations import BodyState
from models.humanoid.stance import guard_pose
from models.tracking.bouts import BoutTracker
from models.tracking.clips import TrackingData, reference_clip, tracking_data
from models.tracking.config import TrackConfig
from models.tracking.matched import MatchedTracker, cross_fade
from models.tracking.matching import MatchConfig, motion_database
from models.tracking.task import TRACK_OBSERVATION_DIM

BONES = (BoneLengths(), BoneLengths())
FIELDS = tuple(BodyState.__dataclass_fields__)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def footage(assets) -> list[tuple[str, np.ndarray, np.ndarray]]:
    return walk_punch_footage(assets)


@pytest.fixture(scope="module")
def data(footage) -> TrackingData:
    """Agent 0 the fighter of the footage, agent 1 its partner, clip for clip."""
    qpos = ({n: q for n, q, _ in footage}, {n: p for n, _, p in footage})
    return tracking_data(qpos, BONES, fps=30.0, key="clips:walk,punch")


def _rows(state: BodyState, rows) -> BodyState:
    return BodyState(*(getattr(state, f)[rows] for f in FIELDS))


def test_an_episode_start_eases_the_match_in_from_the_body_as_it_stood(footage):
    """Over `ease_steps` steps the reference goes from the standing body (held still) to the
    match, along the cross-fade; from then on it is the match as a tracker without the ease
    plays it."""
    own = [reference_clip(n, q, BONES[0], fps=30.0) for n, q, _ in footage]
    others = [reference_clip(f"{n}:p", p, BONES[1], fps=30.0) for n, _, p in footage]
    ease = 10
    # No searches after the start, so both trackers play the same frames.
    config = MatchConfig(ease_steps=ease, search_every=1000, blend_steps=0)
    db = motion_database(own, others, fps=30.0, config=config)
    plain_db = dataclasses.replace(db, config=dataclasses.replace(config, ease_steps=0))
    eased, plain = MatchedTracker(None, db), MatchedTracker(None, plain_db)
    # The fighter stands in the punch's first pose, 4 m from its partner (the walk's distance,
    # so the match is the walk: another pose than the one it stands in).
    body = _rows(db.library.clip.states, [db.library.start[1]])
    still = BodyState(body.pos, body.rot, 0 * body.lin_vel, 0 * body.ang_vel)
    partner = _rows(db.partner, [db.library.start[0]])
    both = BodyState(*(np.stack([getattr(still, f), getattr(partner, f)], 1) for f in FIELDS))
    seen = Seen(np.arange(1), 0, both, np.zeros((1, 0)), np.zeros((1, 0)))
    eased.reset(seen)
    plain.reset(seen)
    walk = db.library.locate(eased.frames(np.arange(1)))[0][0]
    assert walk == 0
    moved = []
    for k in range(ease + 3):
        a, b = eased.reference(np.arange(1)), plain.reference(np.arange(1))
        w = min(1.0, 1.0 - (ease - k) / (ease + 1))
        want = cross_fade(still, b, np.array([w])) if k < ease else b
        for f in FIELDS:
            np.testing.assert_allclose(getattr(a, f), getattr(want, f), atol=1e-12)
        moved.append(float(np.linalg.norm(a.pos[0, 0, :2] - still.pos[0, 0, :2])))
        aims = [t.target(seen) for t in (eased, plain)]
        np.testing.assert_array_equal(aims[0].actions, aims[1].actions)  # the match's targets
        for t in (eased, plain):
            t.advance(np.arange(1))
    # At the start the reference is nearly the standing body, and its speed grows from 0.
    assert moved[0] < 0.01 and moved[ease - 1] > 5 * moved[0]
    with pytest.raises(ValueError, match="ease_steps must be >= 0"):
        MatchConfig(ease_steps=-1)


def _bout(data: TrackingData, num_envs: int, **track) -> tuple[ArenaEnv, BoutTracker]:
    config = dataclasses.replace(TRACK.env, num_envs=num_envs, stepping="threads")
    env = ArenaEnv(config, np.random.default_rng(0), BONES)
    return env, BoutTracker(data, TrackConfig(**track), config)


def test_a_bout_starts_both_fighters_at_rest_in_their_guards_where_the_footage_has_them(data):
    env, bout = _bout(data, 6)
    try:
        obs = bout.reset(env, np.arange(6), np.random.default_rng(3))
        assert obs.shape == (6, 2, TRACK_OBSERVATION_DIM) and np.isfinite(obs).all()
        frame = bout.players[0].database.candidates[
            np.random.default_rng(3).integers(len(bout.players[0].database.candidates), size=6)
        ]
        for i, datum in enumerate(env.datas):
            qpos, qvel = datum.qpos.reshape(2, -1), datum.qvel.reshape(2, -1)
            assert np.abs(qvel).max() == 0.0
            for a in range(2):
                clip = data.clips[a]
                guard = guard_pose(BONES[a], np.concatenate([c.qpos for c in clip]))
                np.testing.assert_allclose(qpos[a, 7:], guard)
            # Where the footage has the two pelvises at that frame, on the floor.
            filmed = [p.database.library.clip.qpos[frame[i], :2] for p in bout.players]
            np.testing.assert_allclose(qpos[:, :2], np.stack(filmed), atol=1e-9)
        lowest = [
            geom_bottoms(
                env.model, env.datas[i], np.flatnonzero(env.index.agent_of_geom == a)
            ).min()
            for i in range(6)
            for a in range(2)
        ]
        assert max(abs(z) for z in lowest) < 1e-6
        # Each fighter's PD targets are what its own matcher gives for the same start.
        sim = env.body_states(np.arange(6))
        for a in range(2):
            fresh = MatchedTracker(None, bout.players[a].database)
            seen = Seen(np.arange(6), a, sim, np.zeros((6, 0)), np.zeros((6, 0)))
            fresh.reset(seen)
            np.testing.assert_allclose(bout.held[:, a], fresh.target(seen).actions)
        # Stepped with no correction, the reward is DeepMimic's against that reference.
        step = bout.step(env, np.zeros((6, 2, 28)))
        assert ((step.reward > 0) & (step.reward <= 1)).all()
        assert np.isfinite(step.body_error).all() and np.isfinite(step.observation).all()
    finally:
        env.close()


def test_a_run_in_bouts_resumes_from_its_checkpoint_exactly(data):
    """With pushes (their generator is part of the state) and both matchers' episodes."""
    config = dataclasses.replace(
        TRACK,
        env=dataclasses.replace(TRACK.env, stepping="rollout"),
        track=TrackConfig(bouts=True, push_every_s=0.5),
    )
    kinds = []
    expected = resumes_exactly(
        config, data, whole_done=lambda t: kinds.append(type(t.objective.tracker))
    )
    assert kinds == [BoutTracker]
    assert 0 < expected[0]["reward_total"] <= 1 and np.isfinite(expected[0]["body_error_cm"])


def test_bouts_need_footage_that_pairs_up(data):
    odd = dataclasses.replace(data, clips=(data.clips[0], data.clips[1][:1]))
    with pytest.raises(ValueError, match="do not pair up clip for clip"):
        BoutTracker(odd, TrackConfig(bouts=True), TRACK.env)
