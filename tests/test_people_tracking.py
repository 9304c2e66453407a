"""Tests for tasks.pose.people_tracking: assignment against brute force, the box Kalman filter, the
clothing-colour descriptor, and the tracker on synthetic scenes drawn with OpenCV (so colour is
measured from real pixels) whose true identities are known."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import cv2
import numpy as np
import pytest

from tasks.pose.config import TrackerConfig
from tasks.pose.fighters import link_fragments
from tasks.pose.people_tracking import (
    DESCRIPTOR_SIZE,
    BoxKalman,
    Observation,
    Tracker,
    appearance,
    colour_distance,
    count_identity_switches,
    hungarian,
)

FPS = 30.0
WIDTH, HEIGHT = 640, 360
BACKGROUND = (150, 160, 165)  # BGR, a greyish canvas
SKIN = (120, 160, 215)


# --- assignment ------------------------------------------------------------------------------


def brute_force(cost: np.ndarray) -> tuple[int, float]:
    """(pairs, total cost) of the best assignment: most allowed pairs, then least cost."""
    n, m = cost.shape
    best = (0, 0.0)
    small, big = (n, m) if n <= m else (m, n)
    grid = cost if n <= m else cost.T
    for perm in itertools.permutations(range(big), small):
        values = [grid[r, c] for r, c in enumerate(perm) if np.isfinite(grid[r, c])]
        candidate = (len(values), float(sum(values)))
        if candidate[0] > best[0] or (candidate[0] == best[0] and candidate[1] < best[1]):
            best = candidate
    return best


@pytest.mark.parametrize("shape", [(1, 1), (3, 3), (5, 5), (2, 5), (5, 2), (4, 6), (6, 3)])
def test_hungarian_matches_brute_force(shape):
    rng = np.random.default_rng(sum(shape))
    for trial in range(25):
        cost = rng.uniform(-3, 10, size=shape)
        if trial % 5 == 4:
            cost = np.round(cost)  # ties
        cost[rng.random(shape) < (0.1 * (trial % 5))] = np.inf
        rows, cols = hungarian(cost)
        assert len(set(rows)) == len(rows) and len(set(cols)) == len(cols)
        assert np.all(np.diff(rows) > 0)
        assert np.isfinite(cost[rows, cols]).all(), "returned a forbidden pair"
        pairs, total = brute_force(cost)
        assert len(rows) == pairs
        assert cost[rows, cols].sum() == pytest.approx(total)


def test_hungarian_edge_cases():
    for shape in [(0, 0), (0, 3), (3, 0)]:
        rows, cols = hungarian(np.zeros(shape))
        assert rows.shape == cols.shape == (0,)
    rows, cols = hungarian(np.full((2, 3), np.inf))
    assert len(rows) == 0
    # The greedy choice (0, 0) would leave row 1 with only a forbidden column.
    rows, cols = hungarian(np.array([[1.0, 2.0], [0.5, np.inf]]))
    assert rows.tolist() == [0, 1] and cols.tolist() == [1, 0]
    with pytest.raises(ValueError, match="cost"):
        hungarian(np.array([[np.nan]]))
    with pytest.raises(ValueError, match="cost"):
        hungarian(np.zeros(3))


# --- motion ----------------------------------------------------------------------------------


def test_kalman_learns_constant_velocity_and_extrapolates():
    kalman = BoxKalman()
    box = np.array([100.0, 50.0, 180.0, 250.0])
    step = np.array([4.0, -1.0, 4.0, -1.0])
    state = kalman.start(box)
    for k in range(1, 30):
        state = kalman.update(kalman.predict(state), box + k * step)
    np.testing.assert_allclose(state.mean[4:6], [4.0, -1.0], atol=0.05)
    for _ in range(10):
        state = kalman.predict(state)
    np.testing.assert_allclose(state.box(), box + 39 * step, atol=1.0)


# --- appearance ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Person:
    """A drawn person: head and legs of skin, a torso and trunks of the given BGR colours."""

    torso: tuple[int, int, int]
    trunks: tuple[int, int, int]
    height: float = 200.0

    def box(self, x: float, foot: float) -> np.ndarray:
        """(4,) box of this person centred on x with feet at ``foot``."""
        w = 0.4 * self.height
        return np.array([x - w / 2, foot - self.height, x + w / 2, foot])


RED = Person(SKIN, (40, 40, 200))
BLUE = Person(SKIN, (200, 80, 30))
GREEN_SMALL = Person((60, 170, 60), (40, 40, 40), height=110.0)


def draw(people: list[tuple[Person, np.ndarray]]) -> np.ndarray:
    """A frame with the people drawn in order (later ones in front)."""
    image = np.full((HEIGHT, WIDTH, 3), BACKGROUND, dtype=np.uint8)
    for person, box in people:
        x0, y0, x1, y1 = box
        h = y1 - y0
        bands = [(0.0, 0.15, SKIN), (0.15, 0.5, person.torso), (0.5, 0.75, person.trunks)]
        bands.append((0.75, 1.0, SKIN))
        for top, bottom, colour in bands:
            p0 = (int(round(x0)), int(round(y0 + top * h)))
            p1 = (int(round(x1)) - 1, int(round(y0 + bottom * h)) - 1)
            cv2.rectangle(image, p0, p1, colour, thickness=-1)
    return image


def test_appearance_is_two_normalised_histograms_that_tell_people_apart():
    image = draw([(RED, RED.box(150, 300)), (BLUE, BLUE.box(450, 300))])
    red = appearance(image, RED.box(150, 300))
    red_moved = appearance(image, RED.box(150, 300) + np.array([3.0, -2, 3, -2]))
    blue = appearance(image, BLUE.box(450, 300))
    assert red.shape == (DESCRIPTOR_SIZE,)
    half = DESCRIPTOR_SIZE // 2
    assert red[:half].sum() == pytest.approx(1.0) and red[half:].sum() == pytest.approx(1.0)
    assert colour_distance(red, red) == pytest.approx(0.0, abs=1e-6)
    assert colour_distance(red, red_moved) < 0.15
    assert 0.3 < colour_distance(red, blue) <= 1.0
    # Same torso: the upper halves match, so the distance comes from the trunks alone.
    assert colour_distance(red[:half].tolist() + blue[half:].tolist(), blue) < 0.05


def test_black_and_white_trunks_differ():
    black, white = Person(SKIN, (15, 15, 15)), Person(SKIN, (245, 245, 245))
    image = draw([(black, black.box(150, 300)), (white, white.box(450, 300))])
    d = colour_distance(
        appearance(image, black.box(150, 300)), appearance(image, white.box(450, 300))
    )
    assert d > 0.3


def test_appearance_handles_boxes_outside_the_image_and_bad_input():
    image = draw([])
    outside = appearance(image, np.array([700.0, 10, 800, 100]))
    assert outside.sum() == 0
    partly = appearance(image, np.array([600.0, -50, 700, 100]))
    assert partly.sum() == pytest.approx(2.0)
    with pytest.raises(ValueError, match="box"):
        appearance(image, np.array([10.0, 10, 5, 20]))
    with pytest.raises(ValueError, match="image_bgr"):
        appearance(image[..., 0], np.array([0.0, 0, 5, 5]))


# --- the tracker on synthetic scenes ---------------------------------------------------------


@dataclass(frozen=True)
class Actor:
    """Someone in a scene: who they are (truth), how they look, and per frame where they stand
    (x, foot y) and whether the detector sees them."""

    truth: str
    person: Person
    path: np.ndarray  # (F, 2) x, foot y; NaN rows when out of the scene
    seen: np.ndarray  # (F,) bool


def actor(truth, person, xs, foot, unseen=()):
    xs = np.asarray(xs, dtype=np.float64)
    path = np.stack([xs, np.broadcast_to(np.asarray(foot, dtype=np.float64), xs.shape)], axis=1)
    seen = np.ones(len(xs), dtype=bool)
    seen[list(unseen)] = False
    return Actor(truth, person, path, seen & ~np.isnan(xs))


def play(tracker, actors, rng, *, jitter=2.0, frames=None, extra=None):
    """Draw each frame (actors in list order, later ones in front), detect the seen actors with
    jittered boxes, feed the tracker in shuffled order; return per-frame (truth, id) pairs."""
    frames = frames if frames is not None else range(len(actors[0].path))
    history = []
    for f in frames:
        present = [a for a in actors if not np.isnan(a.path[f, 0])]
        image = draw([(a.person, a.person.box(*a.path[f])) for a in present])
        detections = []
        for a in present:
            if a.seen[f]:
                box = a.person.box(*a.path[f]) + rng.normal(0, jitter, 4)
                detections.append((a.truth, box, 0.9))
        detections += extra(f, detections) if extra else []
        order = rng.permutation(len(detections))
        obs = [
            Observation(detections[i][1], detections[i][2], appearance(image, detections[i][1]))
            for i in order
        ]
        ids = tracker.update(obs)
        history.append([(detections[i][0], t) for i, t in zip(order, ids, strict=True)])
    return history


def ids_of(history):
    """truth -> set of track ids it was given."""
    found: dict = {}
    for pairs in history:
        for truth, track in pairs:
            if track is not None and truth is not None:
                found.setdefault(truth, set()).add(track)
    return found


def assert_clean(history, truths):
    """No identity switch, one id per person, no id shared by two people."""
    assert count_identity_switches(history) == 0
    found = ids_of(history)
    assert set(found) == set(truths)
    assert all(len(ids) == 1 for ids in found.values()), found
    every = [i for ids in found.values() for i in ids]
    assert len(every) == len(set(every)), found


def crossing_paths(frames=40, start=120.0, stop=520.0):
    xs = np.linspace(start, stop, frames)
    return xs, xs[::-1].copy()


def test_two_people_crossing_keep_their_ids():
    a_x, b_x = crossing_paths()
    actors = [actor("red", RED, a_x, 290), actor("blue", BLUE, b_x, 310)]
    tracker = Tracker(TrackerConfig(), FPS)
    history = play(tracker, actors, np.random.default_rng(1))
    assert_clean(history, {"red", "blue"})
    assert [t.track_id for t in tracker.tracks()] == [0, 1]


def test_occluded_person_keeps_id_for_ten_frames():
    a_x, b_x = crossing_paths()
    hidden = range(15, 25)  # red walks behind blue: no detection for 10 frames
    actors = [actor("red", RED, a_x, 290, unseen=hidden), actor("blue", BLUE, b_x, 310)]
    tracker = Tracker(TrackerConfig(), FPS)
    history = play(tracker, actors, np.random.default_rng(2), frames=range(15))
    red_id = ids_of(history)["red"].pop()
    history += play(tracker, actors, np.random.default_rng(3), frames=range(15, 25))
    assert red_id in tracker.predict(), "a coasting track is still predicted"
    history += play(tracker, actors, np.random.default_rng(4), frames=range(25, 40))
    assert_clean(history, {"red", "blue"})
    (red,) = [t for t in tracker.tracks() if t.track_id == red_id]
    assert red.frames_observed == 30 and not red.observed[15:25].any()
    assert len(tracker.tracks()) == 2


def meet_and_turn_back():
    """Red and blue walk towards each other, meet, and each goes back the way it came; red is
    hidden behind blue for the 10 frames around the meeting."""
    t = np.arange(40)
    a_x = 320 - 10 * np.abs(t - 20) - 30
    b_x = 320 + 10 * np.abs(t - 20) - 10
    return [actor("red", RED, a_x, 300, unseen=range(15, 25)), actor("blue", BLUE, b_x, 305)]


def test_people_who_meet_and_turn_back_keep_their_ids_by_colour():
    tracker = Tracker(TrackerConfig(), FPS)
    history = play(tracker, meet_and_turn_back(), np.random.default_rng(5))
    assert_clean(history, {"red", "blue"})


def test_a_person_lost_behind_another_is_sought_where_they_were_lost():
    """Without colour too (alpha 1): red's blind prediction walks on into blue, but red comes
    back where it was lost, and a coasting track is also sought at its last box (before, this
    scene swapped ids without colour)."""
    tracker = Tracker(TrackerConfig(alpha=1.0), FPS)
    history = play(tracker, meet_and_turn_back(), np.random.default_rng(5))
    assert_clean(history, {"red", "blue"})


def swap_unseen():
    """Red and blue stand 120 px apart, go unseen for 16 frames (a flash, a blur) while they
    swap places, and stand again: each comes back 20 px from where the other was lost."""
    t = np.arange(40)
    red_x = np.interp(t, [0, 15, 25, 40], [260, 260, 360, 360])
    blue_x = np.interp(t, [0, 15, 25, 40], [380, 380, 280, 280])
    unseen = range(12, 28)
    return [actor("red", RED, red_x, 300, unseen), actor("blue", BLUE, blue_x, 305, unseen)]


def test_people_who_swap_places_unseen_keep_their_ids_by_colour_only():
    tracker = Tracker(TrackerConfig(), FPS)
    assert_clean(play(tracker, swap_unseen(), np.random.default_rng(5)), {"red", "blue"})
    # The control: position alone gives each the other's id.
    tracker = Tracker(TrackerConfig(alpha=1.0), FPS)
    history = play(tracker, swap_unseen(), np.random.default_rng(5))
    assert count_identity_switches(history) > 0


def test_shot_cut_ends_tracks_and_never_reuses_ids():
    a_x, b_x = crossing_paths(frames=20, start=150, stop=250)
    before = [actor("red", RED, a_x, 300), actor("blue", BLUE, b_x + 200, 300)]
    after = [actor("red", RED, a_x + 250, 330), actor("blue", BLUE, b_x - 20, 280)]
    tracker = Tracker(TrackerConfig(), FPS, start_frame=100)
    first = play(tracker, before, np.random.default_rng(6))
    tracker.cut()
    assert tracker.predict() == {}
    second = play(tracker, after, np.random.default_rng(7))
    assert_clean(first, {"red", "blue"})
    assert_clean(second, {"red", "blue"})
    old = set().union(*ids_of(first).values())
    new = set().union(*ids_of(second).values())
    assert old == {0, 1} and new == {2, 3}
    summaries = tracker.tracks()
    assert [(t.first_frame, t.last_frame) for t in summaries] == [(100, 119)] * 2 + [(120, 139)] * 2


def test_third_person_walking_through_gets_its_own_id():
    frames = 60
    t = np.arange(frames)
    spectator_x = np.full(frames, np.nan)
    spectator_x[10:50] = np.linspace(20, 620, 40)
    actors = [
        actor("spectator", GREEN_SMALL, spectator_x, 200),  # behind, smaller
        actor("red", RED, 250 + 30 * np.sin(t / 6), 320),
        actor("blue", BLUE, 400 - 30 * np.sin(t / 7), 325),
    ]
    tracker = Tracker(TrackerConfig(), FPS)
    history = play(tracker, actors, np.random.default_rng(8))
    assert_clean(history, {"red", "blue", "spectator"})
    found = ids_of(history)
    assert found["red"] | found["blue"] == {0, 1} and found["spectator"] == {2}


def test_jitter_missed_frames_duplicates_and_weak_false_alarms():
    frames = 90
    t = np.arange(frames)
    rng = np.random.default_rng(9)
    missed_red = [f for f in range(3, frames, 7)]
    missed_blue = [f for f in range(5, frames, 11)]
    actors = [
        actor("red", RED, 260 + 40 * np.sin(t / 8), 320 + 5 * np.sin(t / 3), unseen=missed_red),
        actor("blue", BLUE, 390 - 40 * np.sin(t / 9), 318, unseen=missed_blue),
    ]

    def extra(f, detections):
        more = []
        if f % 4 == 0 and detections:  # a second, weaker box on the same person
            truth, box, _ = detections[0]
            more.append((truth, box + np.array([4.0, 3, 2, -3]), 0.55))
        if f % 5 == 0:  # a weak false alarm somewhere in the crowd
            more.append((None, np.array([20.0, 40, 60, 120]) + f % 3, 0.3))
        return more

    tracker = Tracker(TrackerConfig(), FPS)
    history = play(tracker, actors, rng, jitter=3.0, extra=extra)
    assert count_identity_switches(history) == 0
    found = ids_of(history)
    assert len(found["red"] | found["blue"]) == 2 and len(tracker.tracks()) == 2
    assert all(track is None for pairs in history for truth, track in pairs if truth is None)


def test_track_coasting_past_the_limit_ends_and_a_new_id_follows():
    config = TrackerConfig(max_coast_s=0.2, min_hits=1)  # 6 frames at 30 fps
    xs = np.full(30, 300.0)
    actors = [actor("red", RED, xs, 300, unseen=range(10, 20))]
    tracker = Tracker(config, FPS)
    history = play(tracker, actors, np.random.default_rng(10))
    assert ids_of(history) == {"red": {0, 1}}
    assert [(t.first_frame, t.last_frame) for t in tracker.tracks()] == [(0, 9), (20, 29)]


def test_new_tracks_wait_min_hits_before_getting_an_id():
    xs = np.full(6, 300.0)
    tracker = Tracker(TrackerConfig(min_hits=3), FPS)
    tracker.update([])  # the person arrives after the shot's first frame
    ids = [ids for ids in play(tracker, [actor("red", RED, xs, 300)], np.random.default_rng(0))]
    assert [pairs[0][1] for pairs in ids] == [None, None, 0, 0, 0, 0]
    (track,) = tracker.tracks()
    assert (track.first_frame, track.frames_observed) == (1, 6)


def test_two_tracks_never_keep_one_body():
    """Red hides behind blue and a second pose of blue (the one red's follower slid onto, same
    keypoints) comes in every frame: red's track must not take blue's body, and takes red
    back when red steps out (issue 33: both tracks followed one pedestrian)."""
    frames = 50
    red_x = np.full(frames, 300.0)
    red_x[:15] = np.linspace(200, 300, 15)
    red_x[35:] = np.linspace(300, 200, 15)
    actors = [
        actor("red", RED, red_x, 300, unseen=range(15, 35)),
        actor("blue", BLUE, np.full(frames, 320.0), 305),
    ]
    keypoints = np.array([[0.0, 0.0], [10.0, 50.0], [20.0, 100.0]])

    def extra(f, detections):
        if not 15 <= f < 35:
            return []
        (blue,) = [box for truth, box, _ in detections if truth == "blue"]
        return [("blue again", blue + 1.0, 0.9)]

    tracker = Tracker(TrackerConfig(), FPS)
    rng = np.random.default_rng(11)
    history = []
    for f in range(frames):
        before = len(history)
        history += play_with_keypoints(tracker, actors, rng, f, extra, keypoints)
        assert len(history) == before + 1
    found = ids_of(history)
    assert found["blue"] == {1} and found["blue again"] == {1}, found
    assert not found["red"] & found["blue"], found
    # Red comes back as a track of its own, which the fighters' linking joins to the first.
    assert count_identity_switches([[(t, i) for t, i in f if t == "red"] for f in history]) <= 1
    _, head_of = link_fragments(tracker.tracks(), max_gap_frames=30)
    assert {head_of[i] for i in found["red"]} == {0}, head_of


def play_with_keypoints(tracker, actors, rng, f, extra, keypoints):
    """One frame of :func:`play` whose observations carry keypoints drawn from their boxes (a
    duplicate of a box gets the same keypoints, give or take a pixel)."""
    present = [a for a in actors if not np.isnan(a.path[f, 0])]
    image = draw([(a.person, a.person.box(*a.path[f])) for a in present])
    detections = [
        (a.truth, a.person.box(*a.path[f]) + rng.normal(0, 1.0, 4), 0.9)
        for a in present
        if a.seen[f]
    ]
    detections += extra(f, detections)
    obs = [
        Observation(box, score, appearance(image, box), box[:2] + keypoints)
        for _, box, score in detections
    ]
    ids = tracker.update(obs)
    return [[(truth, i) for (truth, _, _), i in zip(detections, ids, strict=True)]]


# --- metric, config and input checks ---------------------------------------------------------


def test_count_identity_switches_by_hand():
    assert count_identity_switches([]) == 0
    frames = [
        [("a", 0), ("b", 1)],
        [("a", 0), ("b", None)],  # b missed: no switch, b keeps 1 as its last id
        [("a", 1), ("b", 0)],  # a and b swap: 2 switches
        [("a", 1), ("b", 0)],
        [("a", 1), ("b", 2), ("c", 5)],  # b gets a new id: 1; c is new: 0
    ]
    assert count_identity_switches(frames) == 3


def test_config_and_input_errors_name_the_argument():
    with pytest.raises(ValueError, match="tracker.alpha"):
        TrackerConfig(alpha=1.5)
    with pytest.raises(ValueError, match="tracker.min_hits"):
        TrackerConfig(min_hits=0)
    with pytest.raises(ValueError, match="tracker.low_score"):
        TrackerConfig(low_score=0.8, high_score=0.5)
    with pytest.raises(ValueError, match="fps"):
        Tracker(TrackerConfig(), 0)
    colour = np.zeros(DESCRIPTOR_SIZE)
    with pytest.raises(ValueError, match="Observation.box"):
        Observation(np.array([1.0, 2.0, 3.0]), 0.9, colour)
    with pytest.raises(ValueError, match="Observation.colour"):
        Observation(np.array([0.0, 0, 10, 10]), 0.9, colour[:5])
    with pytest.raises(TypeError, match=r"observations\[0\]"):
        Tracker(TrackerConfig(), FPS).update([np.array([0.0, 0, 10, 10])])
    assert replace(TrackerConfig(), alpha=0.3).alpha == 0.3
