"""The clip library (models.tracking.clips) against hand-worked indices, and the tracker
following the frame source it is given (models.tracking.task)."""

from __future__ import annotations

import numpy as np
import pytest

from models.arena.config import EnvConfig
from models.arena.env import ArenaEnv
from models.humanoid.boxer import BoneLengths
from models.humanoid.observations import SELF_DIM, BodyState
from models.tracking.clips import ClipLibrary, ReferenceClip, clip_library, tracking_data
from models.tracking.config import TrackConfig
from models.tracking.task import NextFrame, Tracker
from tasks.deepmimic import clip_path, load_deepmimic, retarget

BONES = (BoneLengths(), BoneLengths())


def _clip(name: str, frames: int, first: float) -> ReferenceClip:
    """A clip whose every per-frame number is its frame's own label, ``first`` + frame."""
    label = first + np.arange(frames, dtype=float)

    def filled(*shape: int) -> np.ndarray:
        return np.broadcast_to(label.reshape(-1, *[1] * len(shape)), (frames, *shape)).copy()

    states = BodyState(filled(15, 3), filled(15, 3, 3), filled(15, 3), filled(15, 3))
    return ReferenceClip(
        name=name,
        qpos=filled(35),
        qvel=filled(34),
        states=states,
        observation=filled(223),
        com=filled(3),
        actions=filled(28),
        body_mass=np.ones(15),
        body_com=np.zeros((15, 3)),
    )


@pytest.fixture(scope="module")
def library() -> ClipLibrary:
    # Clip 0: frames 0-2 (flat 0-2); clip 1: frames 0-3 (flat 3-6).
    return clip_library([_clip("a", 3, 0.0), _clip("b", 4, 10.0)], fps=30.0)


def test_a_library_names_every_frame_of_its_clips_by_one_flat_index(library):
    assert library.num_clips == 2 and library.clip.name == "a+b"
    np.testing.assert_array_equal(library.start, [0, 3])
    np.testing.assert_array_equal(library.last, [2, 6])
    np.testing.assert_array_equal(library.startable, [0, 1, 3, 4, 5])
    np.testing.assert_array_equal(library.clip.qpos[:, 0], [0, 1, 2, 10, 11, 12, 13])
    np.testing.assert_array_equal(library.clip.states.pos[:, 0, 0], [0, 1, 2, 10, 11, 12, 13])
    np.testing.assert_array_equal(
        library.index(np.array([0, 1, 1]), np.array([2, 0, 3])), [2, 3, 6]
    )
    clip, frame = library.locate(np.array([0, 2, 3, 6]))
    np.testing.assert_array_equal(clip, [0, 0, 1, 1])
    np.testing.assert_array_equal(frame, [0, 2, 0, 3])
    with pytest.raises(ValueError, match="frames must lie in their clips"):
        library.index(np.array([0]), np.array([3]))
    with pytest.raises(ValueError, match="ids must be clip indices"):
        library.index(np.array([2]), np.array([0]))


def test_a_time_names_its_nearest_frame_held_at_the_clips_ends(library):
    ids = np.array([0, 0, 1, 1, 1])
    times = np.array([-1.0, 0.049, 1 / 30, 0.06, 10.0])
    np.testing.assert_array_equal(library.frame(ids, times), [0, 1, 4, 5, 6])


def test_the_next_frame_is_the_clips_own_and_its_last_is_held(library):
    flat = np.array([0, 1, 2, 3, 5, 6])
    np.testing.assert_array_equal(library.next(flat), [1, 2, 2, 4, 6, 6])
    np.testing.assert_array_equal(library.at_end(flat), [False, False, True, False, False, True])
    both = np.stack([flat, flat], 1)
    np.testing.assert_array_equal(NextFrame().next((library, library), both), library.next(both))


class _Hold:
    """A frame source that keeps each agent on its current frame."""

    def next(self, libraries, flat):
        return flat.copy()


def test_the_tracker_follows_the_frame_source_it_is_given(assets):
    walk = retarget(load_deepmimic(clip_path(assets, "walk")))
    data = tracking_data(({"walk": walk}, {"walk": walk}), BONES, fps=30.0, key="walk")
    config = EnvConfig(num_envs=2, threads=1, stepping="threads")
    with ArenaEnv(config, np.random.default_rng(0)) as env:
        tracker = Tracker(data, TrackConfig(), config, source=_Hold())
        obs = tracker.reset(env, np.arange(2), np.random.default_rng(3))
        start = tracker.flat.copy()
        # What the policy is told of the frame to reach is the current frame's o^self.
        told = obs[..., SELF_DIM : 2 * SELF_DIM]
        want = np.stack(
            [f.clip.observation[start[:, a]] for a, f in enumerate(tracker.libraries)], 1
        )
        np.testing.assert_allclose(told, want)
        # The PD targets hold the current frame, and a step stays on it.
        held = tracker.actions(np.zeros((2, 2, 28)))
        np.testing.assert_allclose(held[:, 0], data.clips[0][0].actions[start[:, 0]])
        tracker.step(env, np.zeros((2, 2, 28)))
        np.testing.assert_array_equal(tracker.flat, start)
