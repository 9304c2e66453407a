"""Our batched IK (`models.humanoid.fitting.solve_ik`) against scipy.optimize.least_squares.

    python benchmarks/ik_solvers.py

On the lift's synthetic DeepMimic cases (`tasks.lift.synthetic.make_case`: the four clips x
seeds 0-2, 528 frames; pybullet's wheel, pulled with the dev assets), each lifted with the lift's
own `lift_fighter` and fitted with its own lifted bones, as the lift stage fits them. Every
solver gets what `fit_humanoid` hands `solve_ik` (the same start pose, sites, targets and
weights, with `LiftConfig`'s ik_iterations, ik_damping and ik_face_weight), the same residual
r = w_s (p_s - target_s) and the same analytic Jacobian (`Skeleton.jacobian`):

 - ours: `solve_ik`, every frame of a case at once (the lift's settings);
 - scipy trf: least_squares(method='trf') per frame, the hinge ranges as bounds;
 - scipy lm: least_squares(method='lm') per frame, no bounds (hinges may leave their ranges).

scipy's root rotation is R = exp([omega]_x) R0, so the Jacobian's rotation columns are
multiplied by the SO(3) left Jacobian J_l(omega) (checked against central differences first).

Columns: weighted RMS site error per frame, sqrt(sum w^2 |p - target|^2 / sum w^2), mean and
95th percentile in mm; the share of frames whose cost is more than 1 % above the lowest any
solver reached in that frame with every hinge in range; frames with a hinge out of range; CPU
ms per frame (one thread, best of three runs per case: CPU time is steadier than wall time on a
shared machine). Last line: scipy trf's CPU time per frame over ours.
"""

from __future__ import annotations

import os

# One thread for every solver, set before numpy loads BLAS: a fair, steady comparison on a
# shared 2-core machine (scipy's per-frame solves gain nothing from threads anyway).
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.humanoid.boxer import BoneLengths, boxer_mjcf  # noqa: E402
from models.humanoid.fitting import (  # noqa: E402
    Skeleton,
    body_rotations_from_points,
    fit_humanoid,
    pose_to_qpos,
    qpos_to_pose,
    site_targets,
    solve_ik,
    wrap_to_ranges,
)
from models.humanoid.kinematics import NUM_ACTUATED, qpos_from_body_rotations  # noqa: E402
from models.pose.types import BLAZEPOSE_33  # noqa: E402
from storage.assets import pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.deepmimic import CLIPS  # noqa: E402
from tasks.lift.config import LiftConfig  # noqa: E402
from tasks.lift.lifting import lift_fighter  # noqa: E402
from tasks.lift.synthetic import make_case  # noqa: E402

SEEDS = (0, 1, 2)  # the 12 cases of benchmarks/lift_synthetic.py
REPEAT = 3  # timed runs per case and solver; the fastest counts
D = 6 + NUM_ACTUATED  # step coordinates: root translation, root rotation, hinges
CFG = LiftConfig()

# (skeleton, start qpos (T, 35), site index (S',), targets (T, S', 3), weights (T, S'))
Problem = tuple[Skeleton, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def lifted_cases(assets: Path) -> list[tuple[np.ndarray, BoneLengths]]:
    """The synthetic cases lifted as the lift stage lifts them: (points (T, 33, 3), bones)."""
    out = []
    for seed in SEEDS:
        for clip in CLIPS:
            case = make_case(clip, seed, assets)
            i = case.inputs
            lifted = lift_fighter(
                i.keypoints_2d, i.confidence, i.world_landmarks, case.K, case.R, case.t,
                fps=case.fps,
            )  # fmt: skip
            out.append((lifted.points, lifted.bones))
    return out


def setup(points: np.ndarray, bones: BoneLengths) -> Problem:
    """What `fit_humanoid` hands `solve_ik` (copied from it; `main` checks the two agree)."""
    p = np.asarray(points, dtype=np.float64)
    skeleton = Skeleton.from_model(mujoco.MjModel.from_xml_string(boxer_mjcf(bones)))
    rotations = body_rotations_from_points(p, skeleton)
    root = p[:, [BLAZEPOSE_33.index("left_hip"), BLAZEPOSE_33.index("right_hip")]].mean(1)
    qpos = qpos_from_body_rotations(root, rotations)
    qpos[:, 7:] = wrap_to_ranges(qpos[:, 7:], skeleton.ranges)
    targets, weights = site_targets(p, CFG.ik_face_weight)
    used = np.flatnonzero(weights > 0)
    w = np.broadcast_to(weights[used], (len(p), len(used))).copy()
    return skeleton, qpos, used, targets[:, used], w


def exp_and_left_jacobian(omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """exp([w]_x) and the left Jacobian J_l(w) (exp([w + dw]_x) = exp([J_l dw]_x) exp([w]_x))
    for (n, 3) rotation vectors; the series limits below 1e-6 rad avoid 0/0."""
    theta = np.linalg.norm(omega, axis=-1)[..., None, None]
    k = np.zeros(omega.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -omega[..., 2], omega[..., 1], -omega[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    kk = k @ k
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(t) / t)
    b = np.where(small, 0.5, (1 - np.cos(t)) / t**2)
    c = np.where(small, 1.0 / 6.0, (t - np.sin(t)) / t**3)
    return np.eye(3) + a * k + b * kk, np.eye(3) + b * k + c * kk


class Frame:
    """One frame as a least-squares problem over x = (root position, omega, hinges), (34,);
    forward kinematics is cached so scipy's jac call after fun at the same x reuses it."""

    def __init__(self, problem: Problem, t: int, root_rot0: np.ndarray) -> None:
        skeleton, _, site_index, targets, weights = problem
        self.sk, self.si, self.r0 = skeleton, site_index, root_rot0[None]
        self.tg, self.w = targets[t : t + 1], weights[t : t + 1]
        self._x: np.ndarray | None = None

    def _eval(self, x: np.ndarray) -> tuple:
        if self._x is None or not np.array_equal(x, self._x):
            rot, jl = exp_and_left_jacobian(x[None, 3:6])
            rp = x[None, :3]
            body_pos, _, axes, sites = self.sk.forward(rp, rot @ self.r0, x[None, 6:])
            self._x, self._parts = x.copy(), (rp, jl, body_pos, axes, sites[:, self.si])
        return self._parts

    def fun(self, x: np.ndarray) -> np.ndarray:
        sites = self._eval(x)[-1]
        return (self.w[..., None] * (sites - self.tg)).ravel()

    def jac(self, x: np.ndarray) -> np.ndarray:
        rp, jl, body_pos, axes, sites = self._eval(x)
        j = self.sk.jacobian(rp, body_pos, axes, sites, self.si)  # (1, S', 3, 34)
        j[..., 3:6] = j[..., 3:6] @ jl[:, None]  # d(site)/d(omega) = d(site)/d(step) J_l
        return (j * self.w[..., None, None]).reshape(-1, D)


def run_ours(problem: Problem) -> np.ndarray:
    skeleton, qpos, si, tg, w = problem
    return solve_ik(skeleton, qpos, si, tg, w, dofs=np.arange(D), iterations=CFG.ik_iterations,
                    damping=CFG.ik_damping)  # fmt: skip


def run_scipy(problem: Problem, method: str) -> np.ndarray:
    """least_squares frame by frame from our start; 'trf' with the hinge ranges as bounds."""
    skeleton, qpos, *_ = problem
    root_pos, root_rot0, hinges = qpos_to_pose(qpos)
    x0 = np.concatenate([root_pos, np.zeros_like(root_pos), hinges], axis=1)  # omega = 0
    lo = np.concatenate([np.full(6, -np.inf), skeleton.ranges[:, 0]])
    hi = np.concatenate([np.full(6, np.inf), skeleton.ranges[:, 1]])
    kw = {"bounds": (lo, hi), "tr_solver": "exact"} if method == "trf" else {}
    xs = []
    for t in range(len(qpos)):
        frame = Frame(problem, t, root_rot0[t])
        xs.append(least_squares(frame.fun, x0[t], jac=frame.jac, method=method, **kw).x)
    x = np.array(xs)
    rot, _ = exp_and_left_jacobian(x[:, 3:6])
    return pose_to_qpos(x[:, :3], rot @ root_rot0, x[:, 6:])


SOLVERS: dict[str, Callable[[Problem], np.ndarray]] = {
    f"ours (solve_ik, {CFG.ik_iterations} it)": run_ours,
    "scipy trf (bounds)": lambda p: run_scipy(p, "trf"),
    "scipy lm (no bounds)": lambda p: run_scipy(p, "lm"),
}


def measure(problem: Problem, qpos: np.ndarray) -> dict[str, np.ndarray]:
    """Per frame: weighted RMS site error (mm), cost, whether a hinge is out of its range."""
    skeleton, _, si, tg, w = problem
    root_pos, root_rot, hinges = qpos_to_pose(qpos)
    sites = skeleton.forward(root_pos, root_rot, hinges)[3][:, si]
    cost = (w**2 * ((sites - tg) ** 2).sum(-1)).sum(-1)
    lo, hi = skeleton.ranges[:, 0], skeleton.ranges[:, 1]
    outside = ((hinges < lo - 1e-9) | (hinges > hi + 1e-9)).any(-1)
    return {"rms_mm": 1000 * np.sqrt(cost / (w**2).sum(-1)), "cost": cost, "outside": outside}


def cpu_seconds(fn: Callable[[Problem], np.ndarray], problem: Problem) -> tuple[np.ndarray, float]:
    """(result, the least CPU time of REPEAT runs): a busy neighbour slows wall time more."""
    best = np.inf
    for _ in range(REPEAT):
        start = time.process_time()
        out = fn(problem)
        best = min(best, time.process_time() - start)
    return out, best


def check_jacobian(problem: Problem) -> None:
    """scipy's analytic Jacobian (with J_l) against central differences of its residual, at a
    point away from omega = 0, where J_l matters; a wrong one would handicap scipy."""
    _, qpos, *_ = problem
    root_pos, root_rot0, hinges = qpos_to_pose(qpos[:1])
    rng = np.random.default_rng(0)
    x = np.concatenate([root_pos[0] + 0.05 * rng.normal(size=3), 0.6 * rng.normal(size=3),
                        hinges[0] + 0.1 * rng.normal(size=NUM_ACTUATED)])  # fmt: skip
    frame = Frame(problem, 0, root_rot0[0])
    fd = np.stack([(frame.fun(x + e) - frame.fun(x - e)) / 2e-6 for e in 1e-6 * np.eye(D)], 1)
    error = np.abs(fd - frame.jac(x)).max()
    assert error < 1e-6, f"scipy's Jacobian is off by {error:.1e}"


def main() -> None:
    assets = data_paths().assets
    pull(assets, dev=True, log=lambda _line: None)  # the DeepMimic clips are dev assets
    start = time.perf_counter()
    cases = lifted_cases(assets)
    frames = sum(len(points) for points, _ in cases)
    print(f"{len(cases)} cases, {frames} frames, lifted in {time.perf_counter() - start:.0f} s; "
          f"IK: {CFG.ik_iterations} iterations, damping {CFG.ik_damping}, face weight "
          f"{CFG.ik_face_weight}, {REPEAT} timed runs each, one thread")  # fmt: skip

    first = setup(*cases[0])
    check_jacobian(first)
    # The benchmark is only about the lift's IK if its problem is exactly fit_humanoid's.
    direct = fit_humanoid(*cases[0], iterations=CFG.ik_iterations, damping=CFG.ik_damping,
                          face_weight=CFG.ik_face_weight)  # fmt: skip
    assert np.array_equal(direct, run_ours(first)), "setup() must build fit_humanoid's problem"

    got: dict[str, list[dict[str, np.ndarray]]] = {name: [] for name in SOLVERS}
    cpu = dict.fromkeys(SOLVERS, 0.0)
    for points, bones in cases:
        problem = setup(points, bones)
        for name, fn in SOLVERS.items():
            qpos, seconds = cpu_seconds(fn, problem)
            got[name].append(measure(problem, qpos))
            cpu[name] += seconds
    m = {n: {k: np.concatenate([c[k] for c in runs]) for k in runs[0]} for n, runs in got.items()}
    # Per frame, the lowest cost of the solvers that kept every hinge in range in that frame
    # (lm's unbounded minimum is lower, but not a pose the humanoid can take).
    best = np.min([np.where(r["outside"], np.inf, r["cost"]) for r in m.values()], axis=0)

    print(f"{'solver':24s} {'err mean':>8s} {'p95 mm':>6s} {'>best+1%':>8s} "
          f"{'out of range':>12s} {'CPU ms/frame':>12s}")  # fmt: skip
    for name, r in m.items():
        above = np.mean(r["cost"] > 1.01 * best + 1e-12)
        print(f"{name:24s} {r['rms_mm'].mean():8.2f} {np.percentile(r['rms_mm'], 95):6.2f} "
              f"{above:8.1%} {int(r['outside'].sum()):5d} ({r['outside'].mean():4.0%}) "
              f"{1000 * cpu[name] / frames:12.2f}")  # fmt: skip
    ours, trf = list(SOLVERS)[:2]
    print(f"ik_cpu_per_frame_scipy_trf_over_ours: {cpu[trf] / cpu[ours]:.1f} x")


if __name__ == "__main__":
    main()
