"""Lift stage speed on the bundled two-person sample (100 frames at 60 fps, 1088x1920).

The pose stage's own functions first make its 2D keypoints and world landmarks (not timed);
then the whole lift of the video (camera and floor from the fighters, lift to 3D, humanoid fit,
MuJoCo cleanup against the floor and the other fighter, review video of both humanoids) is
timed, best of 3.
Prints the split of the first run and, last, ``lift_fps: N fps``: frames per second per
fighter (frames lifted, summed over the fighters, over the seconds).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen rendering, as `ringside` sets it
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import tasks.lift.stage as lift  # noqa: E402
from benchmarks._common import FRAMES, Timer, lift_sample, sample_fighters  # noqa: E402
from storage.assets import SAMPLE_VIDEO, pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402


def main() -> None:
    paths = data_paths()
    pull(paths.assets, log=lambda _line: None)
    video = paths.assets / SAMPLE_VIDEO
    fighters = sample_fighters(video, paths.assets)
    timer = Timer()
    for name in ("ground_fighters", "lift_fighter", "fit_humanoid", "cleanup", "cleanup_pair"):
        setattr(lift, name, timer.wrap(name, getattr(lift, name)))
    best, lifted = float("inf"), 0
    for run in range(3):
        start = time.perf_counter()
        out = lift_sample(fighters)
        seconds = time.perf_counter() - start
        if run == 0:
            first = dict(timer.spent), seconds
        best = min(best, seconds)
        lifted = int(out.metrics["adversary_frames_lifted"] + out.metrics["opponent_frames_lifted"])
    split, total = first
    print(
        f"input: {video.name}, {FRAMES} frames, {len(fighters)} fighters, "
        f"{lifted} fighter-frames lifted"
    )
    for name, seconds in sorted(split.items(), key=lambda kv: -kv[1]):
        print(f"  {name:16s} {seconds:6.2f} s  {100 * seconds / total:5.1f} %")
    print(f"  other            {total - sum(split.values()):6.2f} s")
    print(
        f"best of 3: {best:.2f} s; floor penetration {out.metrics['floor_penetration_max_mm']:.1f}"
        f" mm, skating {out.metrics['foot_skating_cm_per_frame']:.3f} cm/frame"
    )
    print(f"lift_fps: {lifted / best:.1f} fps")


if __name__ == "__main__":
    main()
