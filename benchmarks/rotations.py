"""Why three rotation conversions stay our own code rather than scipy's `Rotation`.

    python benchmarks/rotations.py

`models.humanoid.kinematics` converts rotations through scipy's `Rotation`, except
`matrix_to_euler_yxz`, `axis_angle_matrix` and `heading_yaw`. This times each against its scipy
equivalent at the batches the environment's step gives them (N environments x 2 fighters, x 8
three-DoF joints for the Euler angles; N = 1 is the spar's one environment), CPU time per call,
best of 5, and checks the yaw of a fighter lying on its back (its x axis 1e-8 rad from
vertical), where scipy's "ZYX" angles meet gimbal lock. Last line: scipy's time over ours for the
Euler angles at N = 1, the conversion every step of the spar makes.
"""

from __future__ import annotations

import os

# One thread: a per-call cost is what is compared, not how a batch spreads over cores.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import sys  # noqa: E402
import time  # noqa: E402
import timeit  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.humanoid.kinematics import (  # noqa: E402
    axis_angle_matrix,
    heading_yaw,
    matrix_to_euler_yxz,
    quat_to_matrix,
)


def cpu_seconds(fn) -> float:
    """CPU seconds per call of ``fn``, best of 5 (CPU time: the machine may be shared)."""
    number = 1
    while timeit.timeit(fn, number=number, timer=time.process_time) < 0.05:
        number *= 2
    return min(timeit.repeat(fn, number=number, repeat=5, timer=time.process_time)) / number


def main() -> None:
    rng = np.random.default_rng(0)
    ratios = {}
    for n in (1, 8, 64):
        joints = quat_to_matrix(rng.normal(size=(n, 2, 8, 4)))
        yaw = rng.uniform(-3, 3, (n, 2))
        quats = rng.normal(size=(n, 2, 4))
        pairs = {
            "matrix_to_euler_yxz": (
                lambda m=joints: matrix_to_euler_yxz(m),
                lambda m=joints: Rotation.from_matrix(m).as_euler("YXZ"),
            ),
            "axis_angle_matrix": (
                lambda a=yaw: axis_angle_matrix((0.0, 0.0, 1.0), a),
                lambda a=yaw: Rotation.from_rotvec(a[..., None] * [0.0, 0.0, 1.0]).as_matrix(),
            ),
            "heading_yaw": (
                lambda q=quats: heading_yaw(q),
                lambda q=quats: Rotation.from_quat(q, scalar_first=True).as_euler("ZYX")[..., 0],
            ),
        }
        for name, (ours, theirs) in pairs.items():
            mine, scipy_s = cpu_seconds(ours), cpu_seconds(theirs)
            ratios[name, n] = scipy_s / mine
            print(
                f"{name:20s} N = {n:2d}: ours {mine * 1e6:6.1f} us, scipy {scipy_s * 1e6:6.1f} us "
                f"({scipy_s / mine:.1f}x)"
            )
    # A fighter on its back: x axis 1e-8 rad from straight up, true yaw 0.7 rad.
    tilt = Rotation.from_euler("ZYX", [0.7, -np.pi / 2 + 1e-8, 0.4])
    quat = tilt.as_quat(scalar_first=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # scipy warns of the gimbal lock it then reports through
        theirs = Rotation.from_quat(quat, scalar_first=True).as_euler("ZYX")[0]
    print(
        f"yaw of a fighter on its back (true 0.7 rad): ours {heading_yaw(quat):.6f}, "
        f"scipy {theirs:.6f}"
    )
    print(f"rotations_euler_scipy_over_ours_n1: {ratios['matrix_to_euler_yxz', 1]:.1f} x")


if __name__ == "__main__":
    main()
