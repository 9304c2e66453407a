"""Our shot-cut detector against PySceneDetect's, on the tests' cases and on hard ones.

    python benchmarks/cut_detectors.py

The inputs are made from the bundled sample's views (`tasks.ingest` must find a cut to a view of
the same colours; a fight's footage also pans, shakes and flashes): the tests' cases (two shots,
motion only, a mirrored view, a 2x crop), hidden cuts (a jump in time, another camera, a 15 %
pan, a brightness step, 5-frame dissolves, cuts under noise and JPEG, two cuts 13 frames apart,
a cut during a pan) and inputs with no cut (noise, hand-held shake, pans, a zoom, flashes, a fast
box, flat grey frames, a fade to black and back, a slow fade) and fades from one view to another.
Each input is right when exactly its true cuts are found (within a frame). Ours runs as
the ingest stage does (`scan_video`, default settings); PySceneDetect's ContentDetector and
AdaptiveDetector at their defaults and at one setting each chosen before the first run (its
HashDetector and HistogramDetector failed the tests' own cases). Then the time of one pass over
the full-size sample. Why we keep ours is written beside `tasks.ingest.probe.CutDetector`.
Last line: the inputs ours gets right.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

from fades import fade_gains, faded  # noqa: E402
from scenedetect import AdaptiveDetector, ContentDetector, SceneManager, open_video  # noqa: E402

from storage.assets import SAMPLE_VIDEO, pull  # noqa: E402
from storage.files import scratch_dir  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.ingest.config import IngestConfig  # noqa: E402
from tasks.ingest.probe import scan_video  # noqa: E402

SIZE = (272, 480)  # as test_a_cut_to_a_view_of_the_same_colours_is_found shrinks the sample
CUT = 50
ASSETS = data_paths().assets
SAMPLE = ASSETS / SAMPLE_VIDEO
SAMPLES = SAMPLE.parent.parent
DETECTORS = {
    "content": lambda: ContentDetector(),
    "content tuned": lambda: ContentDetector(threshold=15.0, min_scene_len=12),
    "adaptive": lambda: AdaptiveDetector(),
    "adaptive tuned": lambda: AdaptiveDetector(
        adaptive_threshold=2.0, min_content_val=8.0, min_scene_len=12
    ),
}


def read(path: Path, n: int = 100, size=SIZE) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    frames = []
    while len(frames) < n:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(f if size is None else cv2.resize(f, size, interpolation=cv2.INTER_AREA))
    cap.release()
    return frames


def write(folder: Path, name: str, frames: list[np.ndarray], fps: float = 30.0) -> Path:
    """As tests/conftest.py write_video: MPEG-4 Part 2 by OpenCV."""
    path = folder / f"{name}.mp4"
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    assert writer.isOpened()
    for f in frames:
        writer.write(f)
    writer.release()
    return path


def moving_box_frames(n, background, start=0, step=3, size=(128, 96), box=(24, 40)):
    """tests/conftest.py moving_box_frames (step=3 there), with the speed as a parameter."""
    w, h = size
    frames = []
    span = w - box[0] - 16
    for i in range(start, start + n):
        frame = np.full((h, w, 3), background, np.uint8)
        x = 8 + abs((i * step) % (2 * span) - span)
        y = (h - box[1]) // 2
        cv2.rectangle(frame, (x, y), (x + box[0], y + box[1]), (128, 128, 128), -1)
        frames.append(frame)
    return frames


def crop_resize(f, x0, y0, x1, y1, size=SIZE):
    return cv2.resize(f[y0:y1, x0:x1], size, interpolation=cv2.INTER_AREA)


def noisy(f, rng, sigma=10.0, quality=10):
    """Sensor noise, then a JPEG round trip at low quality: blocking and ringing per frame."""
    g = np.clip(f.astype(np.float32) + rng.normal(0, sigma, f.shape), 0, 255).astype(np.uint8)
    ok, jpg = cv2.imencode(".jpg", g, [cv2.IMWRITE_JPEG_QUALITY, quality])
    return cv2.imdecode(jpg, cv2.IMREAD_COLOR)


def dissolved(
    first: list[np.ndarray], then: list[np.ndarray], start: int, end: int
) -> list[np.ndarray]:
    """``first`` dissolving into ``then`` over frames ``start`` to ``end``."""
    steps = end - start + 2
    return [
        first[i]
        if i < start
        else then[i]
        if i > end
        else cv2.addWeighted(
            first[i], 1 - (i - start + 1) / steps, then[i], (i - start + 1) / steps, 0
        )
        for i in range(len(first))
    ]


def shaken(full: list[np.ndarray], amplitude: float, rng) -> list[np.ndarray]:
    """Hand-held shake: a window of 90 % of the frame moved at random by up to ``amplitude`` of
    the width and height each frame."""
    h, w = full[0].shape[:2]
    cw, ch = int(0.9 * w), int(0.9 * h)
    out = []
    for f in full:
        dx, dy = rng.uniform(-amplitude, amplitude) * w, rng.uniform(-amplitude, amplitude) * h
        x0, y0 = int((w - cw) / 2 + dx), int((h - ch) / 2 + dy)
        out.append(crop_resize(f, x0, y0, x0 + cw, y0 + ch))
    return out


def panned(full: list[np.ndarray], speed: float) -> list[np.ndarray]:
    """A steady pan to and fro: a window of 55 % of the width moved ``speed`` of its width a
    frame."""
    h, w = full[0].shape[:2]
    cw = int(0.55 * w)
    out = []
    for i, f in enumerate(full):
        x = int(abs((i * speed * cw) % (2 * (w - cw)) - (w - cw)))
        out.append(crop_resize(f, x, 0, x + cw, h, (272, int(272 * h / cw))))
    return out


def build_inputs(folder: Path) -> list[tuple[str, str, Path, list, int]]:
    """(group, name, path, true cuts (frame or (first, last) of a gradual transition), tol)."""
    a = read(SAMPLE)
    b = read(SAMPLES / "multi_person/cam02.mp4")
    c = read(SAMPLES / "multi_person/cam03.mp4")
    h, w = a[0].shape[:2]
    full = read(SAMPLE, size=None)
    H, W = full[0].shape[:2]
    rng = np.random.default_rng(0)
    out = []

    def add(group, name, frames, cuts, tol=1):
        out.append((group, name, write(folder, name, frames), cuts, tol))

    # (a) the tests' cases
    add(
        "tests",
        "two_shot",
        moving_box_frames(30, (200, 60, 20)) + moving_box_frames(30, (20, 40, 210), 30),
        [30],
    )
    add("tests", "motion_only", moving_box_frames(60, (200, 60, 20)), [])
    add("tests", "mirrored", a[:CUT] + [cv2.flip(f, 1) for f in a[CUT:]], [CUT])
    add(
        "tests",
        "reframed_2x",
        a[:CUT] + [crop_resize(f, w // 4, h // 4, 3 * w // 4, 3 * h // 4) for f in a[CUT:]],
        [CUT],
    )
    add("tests", "sample_272x480", a, [])
    out.append(("tests", "sample_full_1088x1920", SAMPLE, [], 1))

    # (b) hidden cuts
    add("hidden", "jump_20f", a[:CUT] + a[CUT + 20 :], [CUT])  # frame 49 -> frame 70
    add(
        "hidden", "jump_10to30", a[:11] + a[30:], [11]
    )  # frame 10 -> frame 30, a jump in time, same colours
    add("hidden", "other_camera", a[:CUT] + b[CUT:], [CUT])  # cam01 -> cam02, same room
    add("hidden", "other_camera_3", a[:CUT] + c[CUT:], [CUT])  # cam01 -> cam03
    s = int(0.15 * w)
    add(
        "hidden",
        "pan_15pct",
        [crop_resize(f, 0, 0, w - s, h) for f in a[:CUT]]
        + [crop_resize(f, s, 0, w, h) for f in a[CUT:]],
        [CUT],
    )
    add(
        "hidden",
        "brightness_x0.6",
        a[:CUT] + [np.clip(f.astype(np.float32) * 0.6, 0, 255).astype(np.uint8) for f in a[CUT:]],
        [CUT],
    )
    add(
        "hidden",
        "brightness_x0.8",
        a[:CUT] + [np.clip(f.astype(np.float32) * 0.8, 0, 255).astype(np.uint8) for f in a[CUT:]],
        [CUT],
    )
    # dissolves over 5 frames (48..52 blend): any cut found in 47..53 counts
    add("hidden", "dissolve5_other_camera", dissolved(a, b, 48, 52), [(48, 52)], 1)
    blue, red = moving_box_frames(60, (200, 60, 20)), moving_box_frames(60, (20, 40, 210))
    add("hidden", "dissolve5_two_shot", dissolved(blue, red, 28, 32), [(28, 32)], 1)
    # under compression noise (noise sigma 10 + JPEG q10 per frame, then mp4v)
    add(
        "hidden",
        "noisy_mirrored",
        [noisy(f, rng) for f in a[:CUT] + [cv2.flip(f, 1) for f in a[CUT:]]],
        [CUT],
    )
    add("hidden", "noisy_other_camera", [noisy(f, rng) for f in a[:CUT] + b[CUT:]], [CUT])
    # no cut: false-positive checks
    add("no cut", "noisy_sample", [noisy(f, rng) for f in a], [])
    add("no cut", "camera_shake_3pct", shaken(full, 0.03, rng), [])
    pan = panned(full, 0.04)
    add("no cut", "pan_4pct_per_frame", pan, [])
    add("no cut", "camera_shake_1.5pct", shaken(full, 0.015, rng), [])
    add("no cut", "pan_8pct_per_frame", panned(full, 0.08), [])
    # slow zoom in: the crop shrinks 1.5 % per frame from the full frame to 40 %
    zoom = []
    for i, f in enumerate(full):
        k = max(0.4, 0.985**i)
        zw, zh = int(W * k), int(H * k)
        x0, y0 = (W - zw) // 2, (H - zh) // 2
        zoom.append(crop_resize(f, x0, y0, x0 + zw, y0 + zh))
    add("no cut", "zoom_1.5pct_per_frame", zoom, [])
    # photographers' flashes: frames 40-41 and 70 blended 70 % towards white
    white = np.full_like(a[0], 255)
    add(
        "no cut",
        "flashes",
        [
            cv2.addWeighted(f, 0.3, white, 0.7, 0) if i in (40, 41, 70) else f
            for i, f in enumerate(a)
        ],
        [],
    )
    # two cuts 13 frames apart (ours: min_shot_frames 12; PySceneDetect default min_scene_len 15)
    add("hidden", "cuts_13_apart", a[:30] + b[30:43] + c[43:], [30, 43])
    # a cut while the camera pans (4 %/frame): cam01 panning -> cam02 panning
    full_b = read(SAMPLES / "multi_person/cam02.mp4", size=None)
    add("hidden", "cut_during_pan", pan[:CUT] + panned(full_b, 0.04)[CUT:], [CUT])
    # fast motion: the fixture's box, 4x faster (12 px/frame of 128) and bigger
    add("no cut", "fast_box", moving_box_frames(60, (200, 60, 20), step=12, box=(40, 60)), [])
    # flat frames and fades: black from frame 47 to 51 (a 10-frame fade each way), or never
    add("no cut", "flat_grey", [np.full((96, 128, 3), 128, np.uint8)] * 60, [])
    fade = fade_gains(len(a), 38, 10)
    add("no cut", "fade_to_black_and_back", faded(a, fade), [])
    add("no cut", "slow_fade_to_5pct", faded(a, 1 - 0.95 * np.sin(np.linspace(0, np.pi, 100))), [])
    # a fade from cam01 into cam02 (and a 3-frame one): the cut anywhere from the first black
    # frame to the new view at half brightness
    add("fades", "fade_other_camera", faded(a[:52] + b[52:], fade), [(47, 56)], 0)
    fast = fade_gains(len(a), 45, 3)
    add("fades", "fade3_other_camera", faded(a[:50] + b[50:], fast), [(47, 53)], 0)
    return out


def hits(found: list[int], truth: list, tol: int) -> tuple[int, int]:
    """(true cuts found, false cuts)."""
    windows = [
        (t - tol, t + tol) if isinstance(t, int) else (t[0] - tol, t[1] + tol) for t in truth
    ]
    used = set()
    for f in found:
        for k, (lo, hi) in enumerate(windows):
            if lo <= f <= hi and k not in used:
                used.add(k)
                break
    fp = sum(not any(lo <= f <= hi for lo, hi in windows) for f in found)
    return len(used), fp


def ours(path: Path) -> list[int]:
    return [shot.start for shot in scan_video(path, IngestConfig()).shots[1:]]


def pyscenedetect(path: Path, make) -> list[int]:
    manager = SceneManager()
    manager.add_detector(make())
    manager.detect_scenes(open_video(str(path), backend="opencv"))
    return [scene[0].frame_num for scene in manager.get_scene_list()[1:]]


def seconds(fn, rounds: int = 3) -> float:
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    pull(ASSETS)
    names = ["ours", *DETECTORS]
    right = dict.fromkeys(names, 0)
    with scratch_dir("bench") as tmp:
        inputs = build_inputs(Path(tmp))
        print("| input | true cuts | " + " | ".join(names) + " |")
        print("|---" * (len(names) + 2) + "|")
        for group, name, path, truth, tol in inputs:
            found = {"ours": ours(path)}
            found |= {n: pyscenedetect(path, make) for n, make in DETECTORS.items()}
            cells = []
            for n in names:
                hit, false = hits(found[n], truth, tol)
                ok = hit == len(truth) and false == 0
                right[n] += ok
                cells.append("ok" if ok else f"{found[n]}")
            print(f"| {group}: {name} | {truth} | " + " | ".join(cells) + " |")
    print("| inputs right | | " + " | ".join(f"{right[n]} of {len(inputs)}" for n in names) + " |")
    ours_s = seconds(lambda: ours(SAMPLE))
    for n, make in DETECTORS.items():
        taken = seconds(lambda m=make: pyscenedetect(SAMPLE, m))
        print(f"{n}: one pass over {SAMPLE.name} in {taken:.2f} s")
    print(f"ours: one pass over {SAMPLE.name} in {ours_s:.2f} s")
    print(f"cut_inputs_right_ours: {right['ours']} of {len(inputs)} inputs")


if __name__ == "__main__":
    main()
