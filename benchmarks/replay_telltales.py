"""What gives the tracker's replay of the held-out footage away (issue 49, must-show 4).

    python benchmarks/replay_telltales.py DATA RUN

DATA is a data directory, RUN a finished tracker run in it (`ringside train --train-objective
track`; a key prefix will do) on a dataset with held-out footage. This is the evaluation's replay
row without the MAAIP run an evaluation needs: the tracker plays every held-out clip as filmed,
in the evaluation's physics (`tasks.evaluate.stage.tracker_replay`), and the classifier test
(`classifier_row`, the evaluation's seed) tells the adversary's 1-second windows in it from the
held-out footage's. Beside it, the real-against-real level (the train footage against the
held-out footage): what a perfect replay would score. Printed: the tracker's own gate figures,
both rows (AUC with its 95 % interval, feature gap, telltales), and each ankle hinge's angle
(the mean over windows of each window's mean, degrees) and swing (of each window's standard
deviation) in the held-out footage and in the replay.

Last line: ``replay_heldout_auc: A``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from storage.db import connect  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from storage.records import output_metrics  # noqa: E402
from tasks.dataset.store import footage_clips  # noqa: E402
from tasks.evaluate.config import EvaluateConfig  # noqa: E402
from tasks.evaluate.stage import classifier_row, tracker_replay  # noqa: E402
from tasks.evaluate.two_sample import WINDOW_FEATURES, footage_windows  # noqa: E402
from tasks.opponent.export import load_trained  # noqa: E402
from tasks.train.store import finished_run  # noqa: E402

ANKLES = tuple(f"{side}_ankle_{axis}" for side in ("left", "right") for axis in ("y", "x", "z"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="the data directory")
    parser.add_argument("run", help="the tracker run (a key prefix will do)")
    args = parser.parse_args()
    paths = data_paths(args.data)
    with connect(paths.db, read_only=True) as con:
        info = finished_run(con, args.run, "RUN")
        if info.objective != "track":
            raise SystemExit(f"RUN {args.run}: a {info.objective!r} run, not a tracker")
        metrics = output_metrics(con, "train", info.dataset_key, info.run_key)
        heldout = tuple(footage_clips(con, info.dataset_key, split="validation"))
        train = tuple(footage_clips(con, info.dataset_key, split="train"))
    if not heldout:
        raise SystemExit(f"dataset {info.dataset_key[:12]}: no held-out footage to replay")
    tracker = load_trained(paths.artifacts, info, metrics)
    hz = float(tracker.config.env.policy_hz)
    print(
        f"tracker {info.run_key[:12]} at iteration {info.iteration} on dataset "
        f"{info.dataset_key[:12]}: "
        + ", ".join(
            f"{k} {v:.4g}"
            for k, v in metrics.items()
            if k.startswith(("track_finished", "track_body", "track_root", "track_gate"))
        )
    )
    footage = footage_windows([(c.qpos, c.other_qpos, c.bones) for c in heldout], hz)
    level = footage_windows([(c.qpos, c.other_qpos, c.bones) for c in train], hz)
    replay = tracker_replay(tracker, heldout, "held-out")
    seed = EvaluateConfig().seed
    rows = {
        "replay": classifier_row("footage", footage, "replay", replay, seed=seed),
        "train footage (the level)": classifier_row("footage", footage, "train", level, seed=seed),
    }
    for name, row in rows.items():
        if row.auc is None:
            print(f"{name}: not measured, {row.reason}")
            continue
        print(
            f"{name} against the held-out footage ({row.real_windows} windows against "
            f"{row.simulated_windows}): AUC {row.auc:.2f} [{row.auc_low:.2f}, {row.auc_high:.2f}], "
            f"feature gap {row.feature_gap:.2f}; telltales {row.telltales}"
        )
    for stat, what in (("mean", "angle, mean over windows"), ("std", "swing within a window")):
        columns = [WINDOW_FEATURES.index(f"{a}_{stat}") for a in ANKLES]
        for name, windows in (("held-out footage", footage), ("replay", replay)):
            values = np.degrees(windows[:, columns].mean(axis=0)) if len(windows) else []
            print(
                f"ankle {what}, {name} (deg): "
                + ", ".join(f"{a} {v:+.1f}" for a, v in zip(ANKLES, values, strict=False))
            )
    auc = rows["replay"].auc
    print(f"replay_heldout_auc: {'nan' if auc is None else f'{auc:.2f}'}")


if __name__ == "__main__":
    main()
