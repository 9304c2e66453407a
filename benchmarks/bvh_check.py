"""The demo's motion as BVH, read back by readers we did not write: how far from MuJoCo's joints.

    python benchmarks/bvh_check.py [--data DIR]

On a data directory where `make demo` (or `ringside process`) ran: the adversary's lifted motion
of the first video (every shot's file) and the first bout of the newest evaluation, written as
`ringside export-motion` writes them, read with bvhio (PyPI) and, where Debian's `blender` is
installed, imported by Blender's own BVH importer; each joint of each frame is compared with
MuJoCo's forward kinematics of the same qpos. Prints each file's frames, joints and largest
error, then the largest of all.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import mujoco

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
# The tests' BVH readers (tests/bvh_readers.py, free of conftest's set-up).
sys.path.insert(0, str(REPO / "tests"))

from bvh_readers import (  # noqa: E402
    blender_available,
    blender_positions,
    bvhio_positions,
    fk_positions,
)

from models.humanoid.boxer import boxer_mjcf  # noqa: E402
from storage.artifacts import read_bytes  # noqa: E402
from storage.db import connect  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.evaluate.motion_files import BOUTS, BvhFile, bout_files, lifted_files  # noqa: E402
from tasks.evaluate.store import evaluation_artifacts  # noqa: E402
from tasks.ingest.store import load_ingest  # noqa: E402
from tasks.lift.store import load_motion, newest_lift  # noqa: E402


def demo_files(data: Path) -> dict[str, BvhFile]:
    paths = data_paths(data)
    with connect(paths.db, read_only=True) as con:
        (video_id,) = con.execute(
            "SELECT video_id FROM videos ORDER BY registered_at LIMIT 1"
        ).fetchone()
        lift_key, ingest_key = newest_lift(con, video_id)
        ingest = load_ingest(con, video_id, ingest_key)
        motion = load_motion(con, video_id, lift_key)
        files = {
            name: file
            for name, file in lifted_files(motion, ingest.shots, ingest.fps).items()
            if name.startswith("adversary-")
        }
        key, run_key = con.execute(
            "SELECT key, video_id FROM stage_outputs WHERE stage = 'evaluate' "
            "ORDER BY created_at DESC LIMIT 1"
        ).fetchone()
        stored = evaluation_artifacts(con, key, run_key)
    bout = bout_files(read_bytes(paths.artifacts, stored[BOUTS]))
    files["bout00-adversary.bvh"] = bout["bout00-adversary.bvh"]
    return files


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, help="data directory (default: Ringside's)")
    data = data_paths(parser.parse_args().data).root
    readers = {"bvhio": bvhio_positions}
    if blender_available():
        readers["blender"] = blender_positions
    else:
        print("Debian's blender is not installed (apt-get install blender): bvhio only")
    worst = 0.0
    with tempfile.TemporaryDirectory(prefix="ringside-bvh-") as tmp:
        for name, file in demo_files(data).items():
            path = Path(tmp) / name
            path.write_text(file.text)
            model = mujoco.MjModel.from_xml_string(boxer_mjcf(file.bones))
            for reader, positions_of in readers.items():
                names, positions = positions_of(path)
                error = float(abs(positions - fk_positions(model, file.qpos, names)).max())
                worst = max(worst, error)
                print(
                    f"{name} by {reader}: {len(positions)} frames (expected {file.frames}), "
                    f"{len(names)} joints, largest joint error {error * 1000:.4f} mm"
                )
    print(f"bvh_max_joint_error: {worst * 1000:.4f} mm")


if __name__ == "__main__":
    main()
