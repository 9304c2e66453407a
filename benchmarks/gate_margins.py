"""How far the sample stays from the lift's speed gates, and what real human motion reaches.

The lift drops a fighter's frames where the body moves as no boxer can (`tasks.lift.gates`):
where a skeleton is first placed, its distance from the camera changing by more than
`max_depth_ratio` from one frame to the next; once lifted, and again after the cleanup, the
pelvis faster than `max_root_speed_m_s` from one video frame to the next; and the cleanup
lowering a fighter by more than `max_floor_settle_m` to stand him on the floor. A gate the bundled
sample comes near would flip between machines. This runs the pose and lift stages' functions on
the sample (60 fps, two people walking) and prints, per gate, the largest value any of the
sample's frames reaches and its margin to the bound (the bound over the value); beside them,
the fastest 30 Hz step of DeepMimic's run, walk, punch and kick retargeted to the humanoid:
motion a gate must let through.

Last line: ``sample_speed_gate_margin: N x`` (the least margin of the two speed gates).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")  # as `ringside` sets it
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import tasks.lift.stage as lift_stage  # noqa: E402
from benchmarks._common import FPS, FRAMES, lift_sample, sample_fighters  # noqa: E402
from storage.assets import SAMPLE_VIDEO, pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.deepmimic import load_deepmimic, retarget  # noqa: E402
from tasks.lift.gates import GateConfig  # noqa: E402

# What each gate function was given, recorded by wrapping it (the lift calls it by this name).
SEEN: dict[str, list[float]] = {"depth_jumps": [], "too_fast": [], "floating": []}


def _recording(name: str, gate):
    def recorded(values, *args):
        values = np.asarray(values, dtype=np.float64)
        if name == "floating":
            SEEN[name].append(float(np.nanmax(values, initial=0.0)))
        elif name == "depth_jumps":
            depth = np.linalg.norm(values, axis=-1)
            ratio = np.maximum(depth[1:], depth[:-1]) / np.minimum(depth[1:], depth[:-1])
            SEEN[name].append(float(np.nanmax(ratio, initial=1.0)))
        else:
            fps = args[0]
            speed = np.linalg.norm(np.diff(values, axis=0), axis=-1) * fps
            SEEN[name].append(float(np.nanmax(speed, initial=0.0)))
        return gate(values, *args)

    return recorded


def main() -> None:
    assets = data_paths().assets
    pull(assets, dev=True, log=lambda _line: None)
    gates = GateConfig()
    for name in SEEN:
        setattr(lift_stage, name, _recording(name, getattr(lift_stage, name)))
    tracks = sample_fighters(assets / SAMPLE_VIDEO, assets)
    out = lift_sample(tracks)
    rejected = {k: v for k, v in out.metrics.items() if k.startswith("frames_rejected_")}
    print(f"sample: {FRAMES} frames at {FPS:g} fps; frames the gates dropped: {rejected}")
    depth = max(SEEN["depth_jumps"])
    print(
        f"placement depth ratio per frame: largest {depth:.3f}, bound {gates.max_depth_ratio:g}"
        f" (margin in the ratio's excess over 1: {(gates.max_depth_ratio - 1) / (depth - 1):.1f}x)"
    )
    # In the sample's one shot, too_fast is called on each fighter's lifted hips, then on each
    # one's cleaned root.
    half = len(SEEN["too_fast"]) // 2
    lifted, cleaned = SEEN["too_fast"][:half], SEEN["too_fast"][half:]
    bound = gates.max_root_speed_m_s
    margins = []
    for what, speeds in (("lifted pelvis", lifted), ("cleaned root", cleaned)):
        fastest = max(speeds)
        margins.append(bound / fastest)
        print(
            f"{what} speed per video frame: largest {fastest:.2f} m/s, bound {bound:g} m/s "
            f"(margin {bound / fastest:.1f}x)"
        )
    settle = max(SEEN["floating"])
    print(
        f"cleanup's lowering onto the floor: largest {settle:.2f} m, bound "
        f"{gates.max_floor_settle_m:g} m (margin {gates.max_floor_settle_m / settle:.1f}x)"
    )
    for clip in ("run", "walk", "punch", "kick"):
        qpos = retarget(load_deepmimic(assets / "dev" / "motions" / f"humanoid3d_{clip}.txt"))
        speed = np.linalg.norm(np.diff(qpos[:, :3], axis=0), axis=-1) * 30.0
        print(f"DeepMimic {clip}: fastest pelvis step {speed.max():.2f} m/s at 30 Hz")
    print(f"sample_speed_gate_margin: {min(margins):.1f} x")


if __name__ == "__main__":
    main()
