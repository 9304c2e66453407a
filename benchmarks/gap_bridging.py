"""How far a bridged gap is from the motion it stands in for, by the gap's length.

The dataset stage fills gaps of at most `dataset.max_bridge_steps` steps inside a clip
(`tasks.dataset.bridging`) instead of cutting the clip there. This measures what that costs on
motion with a known truth: DeepMimic's punch, kick, run and walk, retargeted to the humanoid at
30 Hz. For every gap length 1-8 steps and every place in each clip a gap of that length fits,
the steps are removed, bridged, and the bridged steps' 33 keypoints (the humanoid's sites, as
the lift stores them) compared with the clip's own: median and 95th percentile over every
keypoint of every bridged step, and the worst wrist. The yardstick beside it is the lift's own
error on real footage, PA-MPJPE 64-77 mm per fighter on the sample (benchmarks/lift_multiview.py).

Last line: ``bridged_2_steps_p95_cm: N cm`` (the default, `dataset.max_bridge_steps` = 2).
"""

from __future__ import annotations

import sys
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from models.humanoid.boxer import BoneLengths, boxer_mjcf  # noqa: E402
from models.humanoid.compiled import keypoint_positions  # noqa: E402
from models.pose.types import BLAZEPOSE_33  # noqa: E402
from storage.assets import pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.dataset.bridging import interpolate_qpos  # noqa: E402
from tasks.dataset.config import DatasetConfig  # noqa: E402
from tasks.deepmimic import load_deepmimic, retarget  # noqa: E402

CLIPS = ("punch", "kick", "run", "walk")
WRISTS = [BLAZEPOSE_33.index("left_wrist"), BLAZEPOSE_33.index("right_wrist")]


def main() -> None:
    assets = data_paths().assets
    pull(assets, dev=True, log=lambda _line: None)
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(BoneLengths()))
    default = DatasetConfig().max_bridge_steps
    truth = {}
    for name in CLIPS:
        qpos = retarget(load_deepmimic(assets / "dev" / "motions" / f"humanoid3d_{name}.txt"))
        truth[name] = (qpos, keypoint_positions(model, qpos))
    print(f"clips: {', '.join(f'{n} {len(q)} steps' for n, (q, _) in truth.items())} at 30 Hz")
    print("gap  median cm  p95 cm  worst wrist cm (clip)")
    headline = None
    for length in range(1, 9):
        errors, wrist = [], (0.0, "")
        for name, (qpos, points) in truth.items():
            for a in range(1, len(qpos) - length):
                b = a + length
                bridged = keypoint_positions(model, interpolate_qpos(qpos[a - 1], qpos[b], length))
                error = np.linalg.norm(bridged - points[a:b], axis=-1) * 100
                errors.append(error.ravel())
                if error[:, WRISTS].max() > wrist[0]:
                    wrist = (float(error[:, WRISTS].max()), name)
        errors = np.concatenate(errors)
        median, p95 = np.median(errors), np.percentile(errors, 95)
        print(f"{length:3d}  {median:9.2f}  {p95:6.2f}  {wrist[0]:14.1f} ({wrist[1]})")
        if length == default:
            headline = p95
    print(f"bridged_{default}_steps_p95_cm: {headline:.2f} cm")


if __name__ == "__main__":
    main()
