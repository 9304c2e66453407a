"""The pose stage's own parts: chunk plans, joining chunks, tiled detection, fighter roles."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from models.pose.blazepose import BlazePoseDetector
from models.pose.tiling import TiledDetector, tile_origins
from tasks.errors import BadInput
from tasks.pose import chunk as chunks
from tasks.pose.chunk import ChunkTracks
from tasks.pose.config import FighterConfig, PoseConfig
from tasks.pose.frames import read_frames
from tasks.pose.merge import ChunkSpan, merge_chunks, summaries
from tasks.pose.people_tracking import DESCRIPTOR_SIZE, appearance
from tasks.pose.stage import BACKENDS, assign_roles, model_files, plan_spans

J = 33


def chunk(
    start: int,
    end: int,
    people: dict[int, tuple[float, int, int]],
    colours: dict[int, np.ndarray] | None = None,
) -> ChunkTracks:
    """A chunk where local track t is a 100x200 box at x = people[t][0] + 2 * frame, seen in
    frames [people[t][1], people[t][2])."""
    rows = [(f, t) for t, (_, a, b) in people.items() for f in range(max(a, start), min(b, end))]
    rows.sort()
    n = len(rows)
    boxes = np.array(
        [[people[t][0] + 2 * f, 100, people[t][0] + 2 * f + 100, 300] for f, t in rows], float
    ).reshape(n, 4)
    colour = np.zeros((n, DESCRIPTOR_SIZE), np.float32)
    for i, (_, t) in enumerate(rows):
        colour[i] = (colours or {}).get(t, np.full(DESCRIPTOR_SIZE, 1 / DESCRIPTOR_SIZE))
    return ChunkTracks(
        start=start,
        end=end,
        seconds=0.0,
        det_frame=np.array([f for f, _ in rows], np.int64),
        det_box=boxes,
        det_score=np.ones(n),
        obs_frame=np.array([f for f, _ in rows], np.int64),
        obs_track=np.array([t for _, t in rows], np.int64),
        obs_box=boxes,
        obs_score=np.ones(n),
        keypoints=np.zeros((n, J, 2), np.float32),
        confidence=np.ones((n, J), np.float32),
        world=np.zeros((n, J, 3), np.float32),
        colour=colour,
    )


def test_plan_spans_overlap_only_within_a_shot():
    spans = plan_spans([(0, 0, 0, 30), (1, 0, 30, 60), (2, 1, 60, 90), (3, 1, 90, 95)], 8)
    assert [(s.start, s.read_start) for s in spans] == [(0, 0), (30, 22), (60, 60), (90, 82)]


def test_chunks_join_by_overlap_and_never_across_a_cut():
    spans = [ChunkSpan(0, 0, 0, 30, 0), ChunkSpan(1, 0, 30, 60, 22), ChunkSpan(2, 1, 60, 90, 60)]
    # In chunk 1 the tracker numbered the same two people the other way round.
    chunks = [
        chunk(0, 30, {0: (0.0, 0, 30), 1: (400.0, 0, 30)}),
        chunk(22, 60, {0: (400.0, 22, 60), 1: (0.0, 22, 60), 2: (800.0, 40, 60)}),
        chunk(60, 90, {0: (0.0, 60, 90)}),
    ]
    merged = merge_chunks(spans, chunks)
    by_track = {
        s.track_id: (s.first_frame, s.last_frame, s.frames_observed) for s in summaries(merged)
    }
    assert by_track == {0: (0, 59, 60), 1: (0, 59, 60), 2: (40, 59, 20), 3: (60, 89, 30)}
    assert merged.track_shot.tolist() == [0, 0, 0, 1]
    left = merged.obs_box[merged.obs_track == 0][:, 0]
    assert np.allclose(np.diff(left), 2), "track 0 swapped people at the chunk border"
    assert not np.any(merged.obs_frame[merged.obs_track == 1] < 0)
    # Each frame appears once per track: the re-read frames 22-29 are not duplicated.
    pairs = list(zip(merged.obs_frame.tolist(), merged.obs_track.tolist(), strict=True))
    assert len(pairs) == len(set(pairs))


def colour_of(bgr: tuple[int, int, int]) -> np.ndarray:
    image = np.full((200, 100, 3), bgr, np.uint8)
    return appearance(image, np.array([0.0, 0.0, 100.0, 200.0]))


def two_shot_tracks():
    """Two shots, each with a red-clad and a blue-clad fighter (swapped sides) and a bystander
    at the edge seen briefly."""
    red, blue, grey = colour_of((30, 30, 200)), colour_of((200, 60, 30)), colour_of((90, 90, 90))
    spans = [ChunkSpan(0, 0, 0, 50, 0), ChunkSpan(1, 1, 50, 100, 50)]
    chunks = [
        chunk(
            0,
            50,
            {0: (200.0, 0, 50), 1: (420.0, 0, 50), 2: (1500.0, 0, 5)},
            {0: red, 1: blue, 2: grey},
        ),
        chunk(50, 100, {0: (200.0, 50, 100), 1: (420.0, 50, 100)}, {0: blue, 1: red}),
    ]
    return merge_chunks(spans, chunks)


def roles_for(tracks, **kwargs):
    options = dict(
        shot_frames={0: 50, 1: 50},
        frame_size=(1920, 1080),
        colour=None,
        pick=None,
        min_share=0.2,
        link_gap_frames=60,
        config=FighterConfig(),
    )
    return assign_roles(tracks, **{**options, **kwargs})


def test_roles_follow_colour_pick_and_appearance():
    tracks = two_shot_tracks()  # ids: shot 0 -> 0 red, 1 blue, 2 bystander; shot 1 -> 3 blue, 4 red
    by_colour = roles_for(tracks, colour="#c81e1e")
    assert by_colour.source == "colour"
    assert by_colour.by_track == {
        0: "adversary",
        1: "opponent",
        2: "other",
        3: "opponent",
        4: "adversary",
    }
    by_pick = roles_for(tracks, pick=1)
    assert by_pick.source == "pick"
    # The pick is blue in shot 0; in shot 1 the blue fighter is found by appearance.
    assert by_pick.by_track == {
        0: "opponent",
        1: "adversary",
        2: "other",
        3: "adversary",
        4: "opponent",
    }
    guessed = roles_for(tracks)
    # Carried to the next shot by appearance, a guess is still a guess (and noted as one).
    assert guessed.source == "guess"
    assert [guessed.by_track[t] for t in (0, 4)] == ["adversary", "adversary"]
    with pytest.raises(BadInput, match="track 9 does not exist"):
        roles_for(tracks, pick=9)


def test_tile_origins_cover_the_long_side():
    assert tile_origins(1088, 1920, 2) == [(0, 0, 1088), (0, 832, 1088)]
    assert tile_origins(1920, 1080, 3) == [(0, 0, 1080), (420, 0, 1080), (840, 0, 1080)]
    assert tile_origins(640, 480, 1) == [(0, 0, 480)]
    with pytest.raises(ValueError, match="tiles must be at least 1"):
        tile_origins(640, 480, 0)


def test_tiles_find_people_the_whole_frame_misses(assets: Path, sample_video: Path):
    detector = BlazePoseDetector(assets / "pose_detection.tflite", num_threads=2)
    tiled = TiledDetector(detector, 2)
    capture = cv2.VideoCapture(str(sample_video))
    whole, tiles = [], []
    for _ in range(20):
        ok, frame = capture.read()
        assert ok
        whole.append(len(detector(frame)))
        found = tiled(frame)
        tiles.append(len(found))
        for det in found:
            assert 0 <= det.box[0] < det.box[2] <= 1088 and 0 <= det.box[1] < det.box[3] <= 1920
    capture.release()
    assert min(tiles) >= 2, tiles
    assert sum(tiles) > sum(whole)


def test_a_person_across_two_tiles_is_one_detection(assets: Path):
    """The single-person sample (1080x1920) on two tiles: the lower tile sees the person's legs,
    cut at its top edge. Found at every detection frame, the person is one detection there,
    not a second person (on an AMD EPYC the legs scored 0.50-0.90 and started a second track)."""
    tiled = TiledDetector(BlazePoseDetector(assets / "pose_detection.tflite", num_threads=2), 2)
    capture = cv2.VideoCapture(str(assets / "samples" / "single_person" / "cam01.mp4"))
    found, frame = [], 0
    while (read := capture.read())[0]:
        if frame % 3 == 0:  # pose.detect_every
            found.append(len(tiled(read[1])))
        frame += 1
    capture.release()
    assert len(found) == 34 and set(found) == {1}, found


def test_a_fighter_lost_for_a_while_is_still_one_fighter():
    red, blue = colour_of((30, 30, 200)), colour_of((200, 60, 30))
    # Track 0 (red) is lost from frame 20 to 29 and comes back as track 2 on its path.
    spans = [ChunkSpan(0, 0, 0, 50, 0)]
    chunks = [
        chunk(
            0,
            50,
            {0: (200.0, 0, 20), 1: (600.0, 0, 50), 2: (200.0, 30, 50)},
            {0: red, 1: blue, 2: red},
        )
    ]
    roles = roles_for(merge_chunks(spans, chunks), shot_frames={0: 50}, colour="#c81e1e")
    assert roles.by_track == {0: "adversary", 1: "opponent", 2: "adversary"}
    unlinked = roles_for(
        merge_chunks(spans, chunks), shot_frames={0: 50}, colour="#c81e1e", link_gap_frames=5
    )
    assert sorted(unlinked.by_track.values()).count("adversary") == 1


def test_a_stopping_flow_ends_its_chunk_at_the_next_frame(assets: Path, sample_video: Path):
    """A stop signal reaches the main thread only; the chunk at work in its thread stops at the
    next frame once the flow sets STOP (Prefect waited for it: a stop took 7-8 s on a loaded
    machine), and a later run's chunks track again."""
    config = PoseConfig()
    detector, estimator = BACKENDS[config.backend].build(*model_files(config, assets), config)
    read: list[int] = []

    def frames(stop_at: int | None):
        for index, frame in read_frames(sample_video, 0, 30):
            read.append(index)
            if index == stop_at:
                chunks.STOP.set()  # as the flow waiting on this chunk stops
            yield index, frame

    def track(stop_at: int | None = None) -> ChunkTracks:
        return chunks.track_chunk(
            frames(stop_at), start=0, end=30, fps=60.0, detector=detector, estimator=estimator,
            config=config,
        )  # fmt: skip

    try:
        with pytest.raises(chunks.Stopped, match="frames 0-30 stopped at frame 5"):
            track(stop_at=5)
        assert read == list(range(6))
    finally:
        chunks.STOP.clear()
    read.clear()
    assert track().obs_frame.max() == 29 and read == list(range(30))
