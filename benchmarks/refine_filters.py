"""Refinement smoothers compared on a synthetic fighter with known truth.

Input: the synthetic bout of tests/test_refine.py, a 33-landmark stick fighter bouncing, stepping
and throwing four straight punches (wrist out ~130 px and back in 10 frames, up to ~41 px/frame),
240 frames at 30 fps; corrupted at noise sigma 1, 3 and 6 px, three fixed seeds each, with
heavy-tailed outliers at lower confidence, left/right flips, dropped frames and joints, and
low-confidence junk. Flips are fixed and short gaps filled at the RefineConfig defaults, then every
smoother in SMOOTHERS runs with the default config's parameters on the same input.

Prints, per smoother and noise level: RMSE against the truth over the points present (px),
jitter_px (px/frame^2), the wrist's mean position error at the punch peaks (px), the worst lag of
the wrist's farthest reach behind the truth's (frames), and milliseconds per call. The winner is
the lowest mean RMSE among smoothers whose jitter is no worse than the input's and that lag no
punch peak by more than 1 frame. Last line: ``refine_best_rmse: N px``, the winner's RMSE averaged
over every noise level and seed.

``--sweep`` also prints small parameter grids per smoother: how the defaults were chosen.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from tasks.pose.config import RefineConfig  # noqa: E402
from tasks.pose.refine import SMOOTHERS, fill_gaps, fix_flips, jitter_px  # noqa: E402
from tests.test_refine import (  # noqa: E402
    FPS,
    GROUPS,
    PERM,
    Corruption,
    corrupt,
    fighter_truth,
    punch_peaks,
    rmse,
)

NOISE_PX = (1.0, 3.0, 6.0)
SEEDS = (11, 12, 13)


@dataclasses.dataclass(frozen=True, eq=False)
class Case:
    """One corrupted bout, cleaned (flips fixed, short gaps filled) and ready to smooth."""

    noise_px: float
    keypoints: np.ndarray  # (T, J, 2)
    confidence: np.ndarray  # (T, J)
    present: np.ndarray  # (T, J) bool


@dataclasses.dataclass(frozen=True)
class Score:
    rmse_px: float
    jitter: float
    peak_error_px: float
    peak_lag: int
    ms: float


def make_cases(truth: np.ndarray, config: RefineConfig) -> list[Case]:
    cases = []
    for noise, seed in itertools.product(NOISE_PX, SEEDS):
        kp, conf, _ = corrupt(truth, np.random.default_rng(seed), noise_px=noise, plan=Corruption())
        kp, conf, _ = fix_flips(kp, conf, PERM, groups=GROUPS, min_confidence=config.min_confidence)
        kp, conf, _ = fill_gaps(
            kp, conf, max_gap=config.max_gap, min_confidence=config.min_confidence
        )
        cases.append(Case(noise, kp, conf, np.isfinite(kp).all(axis=2)))
    return cases


def score(case: Case, truth: np.ndarray, config: RefineConfig) -> Score:
    start = time.perf_counter()
    out = SMOOTHERS[config.smoother](case.keypoints, case.confidence, FPS, config)
    ms = 1000 * (time.perf_counter() - start)
    lags, errors = punch_peaks(out, truth)
    return Score(
        rmse(out, truth, case.present),
        jitter_px(out),
        float(np.mean(errors)),
        max(lags, key=abs),
        ms,
    )


def mean(scores: list[Score]) -> Score:
    return Score(
        float(np.mean([s.rmse_px for s in scores])),
        float(np.mean([s.jitter for s in scores])),
        float(np.mean([s.peak_error_px for s in scores])),
        max((s.peak_lag for s in scores), key=abs),
        float(np.mean([s.ms for s in scores])),
    )


def evaluate(
    cases: list[Case], truth: np.ndarray, config: RefineConfig
) -> tuple[dict[float, Score], Score]:
    """Mean score per noise level, and over all cases."""
    scores = [score(case, truth, config) for case in cases]
    by_noise = {
        noise: mean([s for s, c in zip(scores, cases, strict=True) if c.noise_px == noise])
        for noise in NOISE_PX
    }
    return by_noise, mean(scores)


def row(name: str, noise: str, s: Score) -> str:
    return (
        f"{name:<20} {noise:>6} {s.rmse_px:>8.2f} {s.jitter:>8.2f} "
        f"{s.peak_error_px:>9.2f} {s.peak_lag:>+5d} {s.ms:>7.1f}"
    )


# Parameter grids for --sweep, as RefineConfig overrides.
SWEEPS: dict[str, dict[str, tuple]] = {
    "one_euro": {
        "one_euro_min_cutoff": (0.5, 1.0, 2.0, 4.0, 8.0),
        "one_euro_beta": (0.01, 0.03, 0.1, 0.3),
        "one_euro_d_cutoff": (1.0, 5.0),
    },
    "savitzky_golay": {"sg_window": (5, 7, 9, 11, 13), "sg_order": (2, 3, 4)},
    "confidence_weighted": {
        "cw_window": (5, 7, 9, 11),
        "cw_order": (1, 2),
        "cw_robust_iterations": (0, 1, 2),
    },
    "adaptive_window": {
        "ici_window_max": (13, 17, 21),
        "ici_threshold": (0.75, 1.0, 1.5, 2.0),
        "ici_robust_iterations": (0, 1),
    },
}


def sweep(cases: list[Case], truth: np.ndarray) -> None:
    """Best 5 settings per smoother by mean RMSE; `worst` is the largest ratio of its RMSE to the
    input's over the noise levels (above 1: it makes some noise level worse)."""
    none = evaluate(cases, truth, RefineConfig(smoother="none"))[0]
    print("\nsweep (mean over all cases; best 5 per smoother by RMSE)")
    for name, grid in SWEEPS.items():
        results = []
        for values in itertools.product(*grid.values()):
            overrides = dict(zip(grid, values, strict=True))
            try:
                config = RefineConfig(smoother=name, **overrides)
            except ValueError:
                continue  # e.g. a window too short for the order
            by_noise, overall = evaluate(cases, truth, config)
            worst = max(by_noise[n].rmse_px / none[n].rmse_px for n in NOISE_PX)
            results.append((overall, worst, overrides))
        results.sort(key=lambda item: item[0].rmse_px)
        for s, worst, overrides in results[:5]:
            setting = " ".join(f"{k}={v}" for k, v in overrides.items())
            print(
                f"  {name:<20} rmse {s.rmse_px:5.2f} worst {worst:4.2f} jitter {s.jitter:5.2f} "
                f"peak {s.peak_error_px:5.2f} lag {s.peak_lag:+d}  {setting}"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sweep", action="store_true", help="also print parameter grids")
    args = parser.parse_args()

    truth = fighter_truth()
    default = RefineConfig()
    cases = make_cases(truth, default)
    print(
        f"synthetic bout: {truth.shape[0]} frames x {truth.shape[1]} joints at {FPS:g} fps; "
        f"noise {', '.join(f'{n:g}' for n in NOISE_PX)} px x seeds {SEEDS}; "
        f"truth jitter_px {jitter_px(truth):.2f}"
    )
    header = ("smoother", "noise", "rmse_px", "jitter", "peak_err", "lag", "ms")
    print("{:<20} {:>6} {:>8} {:>8} {:>9} {:>5} {:>7}".format(*header))
    overall = {}
    for name in SMOOTHERS:
        by_noise, overall[name] = evaluate(
            cases, truth, dataclasses.replace(default, smoother=name)
        )
        for noise, s in by_noise.items():
            print(row(name, f"{noise:g}", s))
        print(row(name, "all", overall[name]))
    input_jitter = overall["none"].jitter
    eligible = {
        name: s
        for name, s in overall.items()
        if name != "none" and s.jitter <= input_jitter and abs(s.peak_lag) <= 1
    }
    best = min(eligible, key=lambda name: eligible[name].rmse_px)
    print(
        f"winner: {best} (lowest mean RMSE with jitter no worse than the input's "
        f"{input_jitter:.2f} and peak lag <= 1 frame); RefineConfig default: {default.smoother}"
        + ("" if best == default.smoother else "  <-- MISMATCH, update RefineConfig.smoother")
    )
    if args.sweep:
        sweep(cases, truth)
    print(f"refine_best_rmse: {overall[best].rmse_px:.2f} px")


if __name__ == "__main__":
    main()
