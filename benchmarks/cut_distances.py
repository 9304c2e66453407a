"""How far apart the cut detector's two distances put what is and is not a cut.

    python benchmarks/cut_distances.py

On every bundled sample view (8 videos, 100 frames each): the largest distance between
consecutive frames (no cut), and the distance from frame 49 to frame 50 mirrored and to a 2x crop
of frame 50's centre (a cut to another view of the same scene), by hue-saturation histogram
(`ingest.cut_threshold`) and by grey-thumbnail structure (`ingest.structure_threshold`); then
camera pans and zooms of frame 50 by structure; then each view's lowest contrast, and frame 50
faded to black in steps of a tenth: its contrast, brightness and the colour and structure
distances to the step before (`ingest.flat_contrast`, `ingest.dark_level`). The numbers in those
settings' and `ingest.structure_threshold`'s descriptions come from here. Last line: the smallest
mirrored or cropped structure distance over the largest between consecutive frames.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from benchmarks._common import FRAMES  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.ingest.config import IngestConfig  # noqa: E402
from tasks.ingest.probe import (  # noqa: E402
    grey_thumbnail,
    histogram_distance,
    hs_histogram,
    structure_distance,
)
from tasks.pose.frames import read_frames  # noqa: E402


def frames_of(path: Path) -> list:
    return [frame for _, frame in read_frames(path, 0, FRAMES)]


def distances(a, b) -> tuple[float, float]:
    width = IngestConfig().histogram_width
    colour = histogram_distance(hs_histogram(a, width), hs_histogram(b, width))
    return colour, structure_distance(grey_thumbnail(a)[0], grey_thumbnail(b)[0])


def main() -> None:
    views = sorted((data_paths().assets / "samples").rglob("*.mp4"))
    if not views:
        sys.exit("no sample videos: run `ringside assets pull` first")
    consecutive, cuts = 0.0, 1.0
    for path in views:
        frames = frames_of(path)
        steady = max(distances(a, b)[1] for a, b in zip(frames, frames[1:], strict=False))
        frame, h, w = frames[50], *frames[50].shape[:2]
        mirror = distances(frames[49], cv2.flip(frame, 1))
        crop = distances(
            frames[49], cv2.resize(frame[h // 4 : 3 * h // 4, w // 4 : 3 * w // 4], (w, h))
        )
        consecutive, cuts = max(consecutive, steady), min(cuts, mirror[1], crop[1])
        print(
            f"{path.parent.name}/{path.name}: consecutive frames {steady:.3f}; mirrored cut "
            f"{mirror[1]:.3f} (colour {mirror[0]:.3f}); 2x crop {crop[1]:.3f} "
            f"(colour {crop[0]:.3f})"
        )
        if path == views[0]:
            for share in (0.01, 0.02, 0.05, 0.1):
                shift = int(w * share)
                moved = structure_distance(
                    grey_thumbnail(frame[:, : w - shift])[0], grey_thumbnail(frame[:, shift:])[0]
                )
                print(f"  pan of {share:.0%} of the width per frame: {moved:.3f}")
            # Faded in memory, not encoded: a codec's noise on dark frames only adds to it.
            fades = [(frame * k).round().astype(np.uint8) for k in np.linspace(1, 0.1, 10)]
            for before, after in zip(fades, fades[1:], strict=False):
                colour, structure = distances(before, after)
                print(
                    f"  fading to black: contrast {grey_thumbnail(after)[2]:.1f}, brightness "
                    f"{grey_thumbnail(after)[1]:.0f}, colour "
                    f"{colour:.3f}, structure {structure:.3f} from the step before"
                )
        lowest = min(grey_thumbnail(f)[2] for f in frames)
        print(f"  lowest contrast of a frame: {lowest:.1f} grey levels")
    print(f"structure_cut_margin: {cuts / consecutive:.0f} x")


if __name__ == "__main__":
    main()
