"""Pose stage speed on the bundled two-person sample (1088x1920 H.264, 100 frames, 60 fps).

Runs the stage's own functions end to end (decode, detect, follow + estimate, track, merge,
choose fighters, refine; the review overlay is timed separately) with the default config, and
reports frames per second and the share of time per step. Steps are timed by wrapping the
stage's detector, estimator and frame reader; "track" is what is left of the chunk loop.
Best of 3 runs. Last line: ``pose_fps: N fps`` (without the overlay, which renders only the
first seconds of a video and is a review aid, not part of the analysis).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import tasks.pose.stage as stage  # noqa: E402
from benchmarks._common import FPS, FRAMES, SIZE, Timer, assemble_sample  # noqa: E402
from storage.assets import HEAVY_LANDMARKER, SAMPLE_VIDEO, pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.pose.config import PoseConfig  # noqa: E402
from tasks.pose.stage import model_files, plan_spans, process_chunk  # noqa: E402


def run_once(video: Path, config: PoseConfig, models) -> tuple[float, float, dict[str, float]]:
    timer = Timer()
    real_build = stage.BACKENDS[config.backend].build
    real_frames = stage.read_frames

    def build(detector, pose, cfg):
        d, e = real_build(detector, pose, cfg)
        return timer.wrap("detect", d), timer.wrap("estimate", e)

    stage.BACKENDS[config.backend] = stage.Backend(
        stage.BACKENDS[config.backend].default_detector,
        stage.BACKENDS[config.backend].default_pose,
        build,
    )
    stage.read_frames = lambda *a: timer.wrap_iter("decode", real_frames(*a))
    try:
        spans = plan_spans([(0, 0, 0, FRAMES)], config.overlap_frames)
        start = time.perf_counter()
        chunks = [process_chunk(video, s, FPS, config, models) for s in spans]
        chunk_s = time.perf_counter() - start
        timer.spent["track"] = chunk_s - sum(timer.spent.values())
        stage.read_frames = real_frames
        render = stage.render_overlay
        overlay_s = 0.0

        def timed_render(*a, **k):
            nonlocal overlay_s
            t = time.perf_counter()
            out = render(*a, **k)
            overlay_s = time.perf_counter() - t
            return out

        stage.render_overlay = timed_render
        start = time.perf_counter()
        assemble_sample(video, spans, chunks, config)
        assemble_s = time.perf_counter() - start
        stage.render_overlay = render
        timer.spent["merge+fighters+refine"] = assemble_s - overlay_s
        total = chunk_s + assemble_s - overlay_s
        return total, overlay_s, timer.spent
    finally:
        stage.BACKENDS[config.backend] = stage.Backend(
            stage.BACKENDS[config.backend].default_detector,
            stage.BACKENDS[config.backend].default_pose,
            real_build,
        )
        stage.read_frames = real_frames


def main() -> None:
    paths = data_paths()
    pull(paths.assets, log=lambda _line: None)
    video = paths.assets / SAMPLE_VIDEO
    config = PoseConfig()
    models = model_files(config, paths.assets)
    runs = [run_once(video, config, models) for _ in range(3)]
    total, overlay_s, spent = min(runs, key=lambda r: r[0])
    print(f"input: {video.name}, {FRAMES} frames {SIZE[0]}x{SIZE[1]}, two people + one bystander")
    print(
        f"config: detect_every={config.detect_every} detector_tiles={config.detector_tiles} "
        f"num_threads={config.num_threads} smoother={config.refine.smoother}"
    )
    for name, seconds in sorted(spent.items(), key=lambda kv: -kv[1]):
        print(
            f"  {name:24s} {1000 * seconds / FRAMES:6.2f} ms/frame  {100 * seconds / total:5.1f} %"
        )
    print(f"overlay (not in the total): {1000 * overlay_s / FRAMES:.2f} ms/frame")
    # The heavier landmark model `pose.pose_model` offers (its accuracy: lift_multiview.py).
    heavy = PoseConfig(pose_model=str(paths.assets / HEAVY_LANDMARKER))
    heavy_runs = [run_once(video, heavy, model_files(heavy, paths.assets)) for _ in range(3)]
    heavy_total = min(r[0] for r in heavy_runs)
    print(
        f"with {HEAVY_LANDMARKER}: {FRAMES / heavy_total:.1f} fps, "
        f"{heavy_total / total:.2f}x the default's time"
    )
    print(f"pose_fps: {FRAMES / total:.1f} fps")


if __name__ == "__main__":
    main()
