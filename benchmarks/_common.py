"""Pieces the benchmarks share: the sample clip's facts, its fighters' 2D input, a step timer."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import imageio_ffmpeg

import tasks.lift.stage as lift_stage
from storage.assets import SAMPLE_VIDEO, pull
from storage.paths import data_paths
from tasks.lift.config import LiftStageConfig
from tasks.lift.stage import FighterTrack, fighter_tracks
from tasks.pose.config import PoseConfig
from tasks.pose.stage import assemble, model_files, plan_spans, process_chunk
from tasks.runner import StageOutput

# The bundled two-person sample (and its other camera views): 100 frames, 60 fps, 1088x1920.
FPS, FRAMES, SIZE = 60.0, 100, (1088, 1920)


def sample_fighters(
    video: Path, assets: Path, pose_model: Path | None = None
) -> dict[str, FighterTrack]:
    """Both fighters of a sample video as the pose stage's own functions see them (with the
    default landmark model, or the one `pose_model` names)."""
    config = PoseConfig(pose_model=str(pose_model) if pose_model else "")
    spans = plan_spans([(0, 0, 0, FRAMES)], config.overlap_frames)
    chunks = [process_chunk(video, s, FPS, config, model_files(config, assets)) for s in spans]
    out = assemble_sample(video, spans, chunks, config)
    return fighter_tracks(out.rows["pose_keypoints"], FRAMES)


def assemble_sample(video: Path, spans: list, chunks: list, config: PoseConfig) -> StageOutput:
    """The pose stage's output of a sample video from its tracked chunks (no colour, no pick)."""
    return assemble(
        video,
        spans,
        chunks,
        frames=FRAMES,
        fps=FPS,
        size=SIZE,
        shots={0: FRAMES},
        colour=None,
        pick=None,
        config=config,
    )


def lift_sample(
    fighters: dict[str, FighterTrack],
    calibration: Path | None = None,
    config: LiftStageConfig | None = None,
) -> StageOutput:
    """The lift stage's output for a sample video's fighters, review video included, with the
    default settings or ``config`` (called through the module, so a benchmark may wrap the
    functions it uses)."""
    lift = lift_stage.lift_video(
        fighters,
        fps=FPS,
        size=SIZE,
        shots=[(0, 0, FRAMES)],
        config=config or LiftStageConfig(),
        calibration=calibration,
    )
    return lift_stage.lift_output(lift)


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


def looped_sample(folder: Path, loops: int) -> Path:
    """The bundled sample played ``loops`` times in one file (stream copy: the seams join one
    camera to itself, so they are not cuts)."""
    assets = data_paths().assets
    pull(assets, log=lambda _line: None)
    out = folder / "looped.mp4"
    ffmpeg = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error"]
    source = ["-stream_loop", str(loops - 1), "-i", str(assets / SAMPLE_VIDEO)]
    subprocess.run([*ffmpeg, *source, "-c", "copy", str(out)], check=True)
    return out
