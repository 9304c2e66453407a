"""Pieces the benchmarks share: the sample clip's facts, its fighters' 2D input, a step timer."""

from __future__ import annotations

import time
from pathlib import Path

from tasks.lift.stage import FighterTrack, fighter_tracks
from tasks.pose.config import PoseConfig
from tasks.pose.stage import assemble, model_files, plan_spans, process_chunk

# The bundled two-person sample (and its other camera views): 100 frames, 60 fps, 1088x1920.
FPS, FRAMES, SIZE = 60.0, 100, (1088, 1920)


def sample_fighters(video: Path, assets: Path, artifacts: Path) -> dict[str, FighterTrack]:
    """Both fighters of a sample video as the pose stage's own functions see them."""
    config = PoseConfig()
    spans = plan_spans([(0, 0, 0, FRAMES)], config.overlap_frames)
    chunks = [process_chunk(video, s, FPS, config, model_files(config, assets)) for s in spans]
    out = assemble(
        video,
        spans,
        chunks,
        key="bench",
        video_id=video.stem,
        frames=FRAMES,
        fps=FPS,
        size=SIZE,
        shots={0: FRAMES},
        colour=None,
        pick=None,
        config=config,
        artifacts=artifacts,
    )
    return fighter_tracks(out.rows["pose_keypoints"], FRAMES)


class Timer:
    """Seconds spent per named step, gathered by wrapping the step's function or iterator."""

    def __init__(self):
        self.spent: dict[str, float] = {}

    def wrap(self, name, fn):
        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.spent[name] = self.spent.get(name, 0.0) + time.perf_counter() - start

        return timed

    def wrap_iter(self, name, iterable):
        iterator = iter(iterable)
        while True:
            start = time.perf_counter()
            try:
                item = next(iterator)
            except StopIteration:
                return
            finally:
                self.spent[name] = self.spent.get(name, 0.0) + time.perf_counter() - start
            yield item
