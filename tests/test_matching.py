"""The partner-aware motion matcher (models.tracking.matching) on DeepMimic's walk and punch,
each given a partner: the walk's far away, the punch's within reach."""

from __future__ import annotations

import numpy as np
import pytest
from opponents import facing
from scipy.spatial.transform import Rotation

from models.humanoid.boxer import BoneLengths
from models.humanoid.observations import BodyState
from models.tracking.clips import reference_clip
from models.tracking.matching import (
    FEATURE_GROUPS,
    MatchConfig,
    MatchWeights,
    MotionDatabase,
    body_features,
    motion_database,
    partner_features,
)
from tasks.deepmimic import clip_path, load_deepmimic, retarget

BONES = BoneLengths()
FPS = 30.0


@pytest.fixture(scope="module")
def clips(assets):
    walk = retarget(load_deepmimic(clip_path(assets, "walk")))
    punch = retarget(load_deepmimic(clip_path(assets, "punch")))
    own = [
        reference_clip("walk", walk, BONES, fps=FPS),
        reference_clip("punch", punch, BONES, fps=FPS),
    ]
    # The walk's partner 4 m ahead (out of reach all the clip), the punch's 0.7 m.
    partners = [
        reference_clip("walk-partner", facing(walk, 4.0), BONES, fps=FPS),
        reference_clip("punch-partner", facing(punch, 0.7), BONES, fps=FPS),
    ]
    return own, partners


@pytest.fixture(scope="module")
def database(clips) -> MotionDatabase:
    return motion_database(*clips, fps=FPS)


def turned(state: BodyState, yaw: float, shift: np.ndarray) -> BodyState:
    """``state`` turned by ``yaw`` about the vertical through the origin, then moved by
    ``shift``."""
    r = Rotation.from_euler("z", yaw).as_matrix()
    return BodyState(
        state.pos @ r.T + shift, r @ state.rot, state.lin_vel @ r.T, state.ang_vel @ r.T
    )


def test_a_frame_of_the_footage_matches_itself_wherever_and_whichever_way_it_is_played(database):
    lib = database.library
    frames = database.candidates[::7]
    me, other = lib.clip.states[frames], database.partner[frames]
    raw = database.query(me, other, frames)
    np.testing.assert_allclose(raw, database.features[frames], atol=1e-9)
    assert database.nearest(raw, np.full(len(frames), -1)).tolist() == frames.tolist()
    # The whole scene turned and moved: the same features, the same match.
    yaw, shift = 2.1, np.array([3.0, -1.5, 0.0])
    moved = database.query(turned(me, yaw, shift), turned(other, yaw, shift), frames)
    np.testing.assert_allclose(moved, raw, atol=1e-9)


def test_with_the_partner_in_reach_the_walker_is_matched_to_the_punch(clips, database):
    lib = database.library
    walking = database.candidates[database.candidates <= lib.last[0]]  # the walk's, 9 frames
    me = lib.clip.states[walking]
    # The punch's partner (0.7 m ahead) where it stands to each walking frame as to the punch's
    # first: turned with the walker's heading, about its pelvis.
    punching = lib.clip.states[lib.start[1]]
    partner = database.partner[lib.start[1]]
    yaws = np.arctan2(me.rot[:, 0, 1, 0], me.rot[:, 0, 0, 0])
    yaw0 = np.arctan2(punching.rot[0, 1, 0], punching.rot[0, 0, 0])
    centred = BodyState(
        partner.pos - punching.pos[0] * [1, 1, 0], partner.rot, partner.lin_vel, partner.ang_vel
    )
    placed = [turned(centred, y - yaw0, me.pos[k, 0] * [1, 1, 0]) for k, y in enumerate(yaws)]
    near = BodyState(
        *(np.stack([getattr(p, f) for p in placed]) for f in BodyState.__dataclass_fields__)
    )
    assert np.allclose(partner_features(me, near)["partner_distance"], 0.7, atol=0.05)
    found = database.nearest(database.query(me, near, walking), np.full(len(walking), -1))
    clip, _ = lib.locate(found)
    assert (clip == 1).all(), f"the walk's frames matched {found} with the partner in reach"

    # Without the partner's features the same query stays in the walk, at the frames given.
    blind = MatchWeights(**{g: 0.0 for g in FEATURE_GROUPS if g.startswith("partner_")})
    unaware = motion_database(*clips, fps=FPS, config=MatchConfig(weights=blind))
    found = unaware.nearest(unaware.query(me, near, walking), np.full(len(walking), -1))
    assert found.tolist() == walking.tolist()


def test_the_kd_tree_finds_what_the_brute_force_finds(database):
    rng = np.random.default_rng(4)
    frames = rng.choice(database.candidates, 200)
    noise = rng.normal(0.0, 1.0, (200, database.features.shape[1])) * database.features.std(0)
    query = database.features[frames] + 0.3 * noise
    playing = np.where(rng.random(200) < 0.5, frames, -1)
    found = database.nearest(query, playing)
    np.testing.assert_array_equal(found, database.nearest_brute(query, playing))
    assert np.isin(found, database.candidates).all()


def test_a_search_leaves_out_the_played_neighbourhood_and_frames_without_a_future(database):
    lib, skip = database.library, database.config.skip_frames
    future = int(database.future_steps.max())
    clip, frame = lib.locate(database.candidates)
    assert (lib.start[clip] + frame + future <= lib.last[clip]).all()
    assert not np.isin(lib.last, database.candidates).any()
    # Each frame asked for itself while it plays: a frame outside its neighbourhood comes back.
    frames = database.candidates
    found = database.nearest(database.features[frames], frames)
    same = lib.locate(found)[0] == lib.locate(frames)[0]
    assert not (same & (np.abs(found - frames) <= skip)).any()


def test_footage_shorter_than_the_neighbourhood_matches_within_it(clips):
    """The walk alone (1.3 s: 9 candidates, all within `skip_frames` of one another, as in the
    demo's 1.4 s sample): a search while it plays finds the nearest frame of all, as one that
    plays nothing does, by both searches, instead of failing mid-bout."""
    (walk, _), (partner, _) = clips
    alone = motion_database([walk], [partner], fps=FPS)
    frames = alone.candidates
    assert np.ptp(frames) <= alone.config.skip_frames
    query = alone.features[frames[::-1]]
    found = alone.nearest(query, frames)
    np.testing.assert_array_equal(found, alone.nearest(query, np.full(len(frames), -1)))
    np.testing.assert_array_equal(found, alone.nearest_brute(query, frames))
    np.testing.assert_array_equal(found, frames[::-1])


def test_bad_clips_are_refused_naming_what_is_wrong(clips):
    own, partners = clips
    with pytest.raises(ValueError, match="clip 'walk': .* frames, its partner's"):
        motion_database(own[:1], partners[1:], fps=FPS)
    short = [reference_clip("short", own[0].qpos[:20], BONES, fps=FPS)]
    with pytest.raises(ValueError, match="no clip is longer than the matcher's future"):
        motion_database(short, short, fps=FPS)
    with pytest.raises(ValueError, match="match weights must be >= 0, got hands"):
        MatchWeights(hands=-1.0)


def test_body_features_are_the_limbs_around_the_pelvis(clips):
    (walk, _), _ = clips
    groups = body_features(walk.states)
    assert groups["feet"].shape == (walk.num_frames, 6)
    # Standing upright, the feet are about a leg below the pelvis, the hands above them.
    assert (groups["feet"][:, 2::3] < -0.6).all()
    assert (groups["hands"][:, 2::3] > groups["feet"][:, 2::3]).all()
