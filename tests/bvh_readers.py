"""Joint positions of a BVH file as readers we did not write compute them, and as MuJoCo does:
the tests' and `benchmarks/bvh_check.py`'s (which imports this file directly; no side effects,
unlike conftest)."""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
from pathlib import Path

import bvhio
import mujoco
import numpy as np

from models.humanoid.compiled import forward_kinematics_batch
from models.humanoid.kinematics import BODY_NAMES, Y_UP_TO_Z_UP

BLENDER_SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "blender_bvh.py"


def bvhio_positions(path: Path) -> tuple[list[str], np.ndarray]:
    """Joint names and (T, J, 3) world positions in metres, z up, as bvhio computes them."""
    root = bvhio.readAsHierarchy(str(path))
    names = [joint.Name for joint, _, _ in root.layout()]
    frames = len(root.Keyframes)
    out = np.empty((frames, len(names), 3))
    for t in range(frames):
        root.loadPose(t, recursive=True)
        for j, (joint, _, _) in enumerate(root.layout()):
            out[t, j] = Y_UP_TO_Z_UP @ np.array(joint.PositionWorld) / 100.0
    return names, out


def blender_available() -> bool:
    return shutil.which("blender") is not None


def blender_positions(path: Path) -> tuple[list[str], np.ndarray]:
    """Joint names and (T, J, 3) world positions in metres as Blender's own BVH importer puts
    them (headless, `benchmarks/blender_bvh.py`)."""
    with tempfile.TemporaryDirectory(prefix="ringside-blender-") as tmp:
        out = Path(tmp) / "positions.json"
        subprocess.run(
            ["blender", "-b", "--factory-startup", "--python", str(BLENDER_SCRIPT), "--"]
            + [str(path), str(out)],
            check=True,
            capture_output=True,
            timeout=300,
        )
        imported = json.loads(out.read_text())
    return imported["joints"], np.array(imported["positions"]).reshape(imported["frames"], -1, 3)


def fk_positions(model: mujoco.MjModel, qpos: np.ndarray, names: list[str]) -> np.ndarray:
    """(T, J, 3) MuJoCo's body positions of the joints ``names`` for one humanoid's qpos."""
    positions, _ = forward_kinematics_batch(model, qpos)
    return positions[:, [BODY_NAMES.index(n) for n in names]]
