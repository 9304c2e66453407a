"""How the pose stage's work is split does not change what it sees: one chunk or many, one
thread or two, the sample's keypoints agree (tests/test_pose_stage.py checks the same against a
Dask cluster)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tasks.pose.config import PoseConfig
from tasks.pose.merge import merge_chunks
from tasks.pose.stage import model_files, plan_spans, process_chunk

FRAMES, FPS = 100, 60.0
# The largest keypoint difference allowed between two splits of the work, in pixels (the
# sample's people are 700-1100 px tall). On one machine they agree to the bit; the tolerance
# is for a chunk computed by another process or machine (Dask), whose kernels may round
# differently.
TOLERANCE_PX = 0.5


def observations(
    video: Path, assets: Path, chunk_frames: int, config: PoseConfig
) -> dict[tuple[int, int], np.ndarray]:
    """(frame, track) -> (33, 2) keypoints of the sample tracked in chunks of ``chunk_frames``
    and merged, as the pose stage does before it picks the fighters."""
    chunks = [
        (i, 0, start, min(start + chunk_frames, FRAMES))
        for i, start in enumerate(range(0, FRAMES, chunk_frames))
    ]
    spans = plan_spans(chunks, config.overlap_frames)
    models = model_files(config, assets)
    tracks = merge_chunks(spans, [process_chunk(video, s, FPS, config, models) for s in spans])
    return {
        (int(f), int(t)): k
        for f, t, k in zip(tracks.obs_frame, tracks.obs_track, tracks.keypoints, strict=True)
    }


def largest_difference(a: dict, b: dict) -> float:
    assert a.keys() == b.keys(), sorted(set(a) ^ set(b))[:10]
    return max(float(np.abs(a[k] - b[k]).max()) for k in a)


@pytest.fixture(scope="module")
def one_chunk(sample_video, assets) -> dict[tuple[int, int], np.ndarray]:
    return observations(sample_video, assets, FRAMES, PoseConfig())


@pytest.mark.parametrize("chunk_frames", [20, 30, 50])
def test_chunks_see_the_keypoints_one_chunk_sees(sample_video, assets, one_chunk, chunk_frames):
    """Before, a chunk started its landmark tracking afresh: from frame 30 on, 30-frame chunks
    put the keypoints a median 10 px and up to 460 px from where one chunk put them, and the
    lift dropped 2 steps of the sample. Both people are seen in all 100 frames either way."""
    chunked = observations(sample_video, assets, chunk_frames, PoseConfig())
    assert len(chunked) == 2 * FRAMES
    assert largest_difference(one_chunk, chunked) <= TOLERANCE_PX


def test_one_landmark_thread_sees_what_two_see(sample_video, assets, one_chunk):
    one_thread = observations(sample_video, assets, FRAMES, PoseConfig(num_threads=1))
    assert largest_difference(one_chunk, one_thread) <= TOLERANCE_PX


def test_a_chunk_must_reread_a_detection_frame():
    """With fewer frames re-read than `detect_every`, a chunk could start following people
    from crops one long chunk never used: refused, naming both settings."""
    with pytest.raises(ValueError, match="overlap_frames.*detect_every"):
        PoseConfig(detect_every=5, overlap_frames=4)
