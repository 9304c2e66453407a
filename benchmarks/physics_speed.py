"""Speed of the two-fighter training environment (models.arena.env) on this machine's CPUs.

N = 64 environments start at random frames of a synthetic interaction (DeepMimic's punch,
retargeted to the boxer, performed by both fighters 1.2 m apart, facing each other) and are
stepped with zero actions. Prints, as environment steps per second (policy steps, all
environments, both agents stepped; each policy step is `substeps` physics steps):

- raw physics (`ArenaEnv.step_physics`: the physics steps only) for both steppings
  ("rollout": mujoco.rollout, the default; "threads": our own pool over the MjData), 1 and
  2 threads, 60 Hz x 2 substeps (the paper's) and 120 Hz x 4;
- for reference, MuJoCo 4's `mujoco.batch.Batch` (raw physics only; the environment does not
  use it: a prototype of the whole step on it ran no faster than "rollout", since the step is
  bound by the observations);
- the whole `ArenaEnv.step` (targets, physics, contacts, kinematics, observations, falls);
- the cost of the observations alone per policy step: `world_frames` copied from every
  environment and one vectorised body-state pass, then one vectorised `observation` call.

Each configuration is timed over 15 steps from a fresh reset, several times, round-robin
with the others so that load from other processes falls on all alike; the best and the
median repeat are printed. Last line: ``physics_steps_per_s: V steps/s``, raw physics of the
default configuration (EnvConfig()).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import mujoco
import mujoco.batch
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from models.arena.config import EnvConfig  # noqa: E402
from models.arena.env import ArenaEnv  # noqa: E402
from models.humanoid.boxer import boxer_mjcf  # noqa: E402
from models.humanoid.compiled import velocities  # noqa: E402
from models.humanoid.observations import observation  # noqa: E402
from models.maaip.demonstrations import ReferenceMotions, facing_reference  # noqa: E402
from storage.assets import pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.deepmimic import clip_path, load_deepmimic, retarget  # noqa: E402

NUM_ENVS = 64
STEPS = 15  # per repeat: half a second, before zero-action fighters start to fall
REPEATS = 7
SEED = 0


def punch_reference() -> ReferenceMotions:
    assets = data_paths().assets
    pull(assets, dev=True, log=lambda _line: None)
    qpos = retarget(load_deepmimic(clip_path(assets, "punch")))
    model = mujoco.MjModel.from_xml_string(boxer_mjcf())
    return facing_reference(qpos, velocities(model, qpos, 30.0), distance=1.2)


@dataclass
class Case:
    """One configuration to time: `prepare` resets it (untimed), `run` is one policy step of
    every environment."""

    what: str
    config: EnvConfig
    prepare: Callable[[], None]
    run: Callable[[], None]
    rates: list[float] = field(default_factory=list)


def env_case(what: str, env: ArenaEnv, reference: ReferenceMotions, full: bool) -> Case:
    zeros = np.zeros((env.num_envs, 2, 28))
    run = (lambda: env.step(zeros)) if full else env.step_physics
    return Case(what, env.config, lambda: env.reset(np.arange(env.num_envs), reference), run)


def batch_case(env: ArenaEnv, reference: ReferenceMotions) -> Case:
    """Raw physics with mujoco.batch.Batch from the environment's reset states."""
    batch = mujoco.batch.Batch(env.model, env.num_envs, nthread=env.config.threads, persistent=True)

    def prepare() -> None:
        env.reset(np.arange(env.num_envs), reference)
        batch.qpos[:] = np.stack([d.qpos for d in env.datas])
        batch.qvel[:] = np.stack([d.qvel for d in env.datas])
        batch.ctrl[:] = 0.0

    return Case(
        "raw physics, mujoco.batch (ref.)",
        env.config,
        prepare,
        lambda: batch.step(nstep=env.config.substeps),
    )


def time_cases(cases: list[Case]) -> None:
    """Round-robin repeats, so that load from other processes hits every case alike; the
    first round only warms up."""
    for round_ in range(REPEATS + 1):
        for case in cases:
            case.prepare()
            start = time.perf_counter()
            for _ in range(STEPS):
                case.run()
            seconds = time.perf_counter() - start
            if round_:
                case.rates.append(NUM_ENVS * STEPS / seconds)


def main() -> None:
    reference = punch_reference()
    rng = np.random.default_rng(SEED)
    envs: list[ArenaEnv] = []
    cases: list[Case] = []

    def env(**kwargs) -> ArenaEnv:
        envs.append(ArenaEnv(EnvConfig(num_envs=NUM_ENVS, **kwargs), rng))
        return envs[-1]

    for substeps in (2, 4):
        for stepping in ("threads", "rollout"):
            for threads in (1, 2):
                made = env(threads=threads, substeps=substeps, stepping=stepping)
                cases.append(env_case(f"raw physics, {stepping}", made, reference, full=False))
        for threads in (1, 2):
            cases.append(batch_case(env(threads=threads, substeps=substeps), reference))
    for stepping in ("threads", "rollout"):
        for threads in (1, 2):
            made = env(threads=threads, stepping=stepping)
            cases.append(env_case(f"full step(), {stepping}", made, reference, full=True))
    try:
        time_cases(cases)
    finally:
        for made in envs:
            made.close()

    print(f"N = {NUM_ENVS} environments, zero actions; environment steps/s (best of {REPEATS})")
    print(f"{'what':34s} {'physics':>8s} {'threads':>7s} {'best':>7s} {'median':>7s}")
    for case in cases:
        c = case.config
        hz = f"{c.policy_hz * c.substeps}x{c.substeps}"
        print(
            f"{case.what:34s} {hz:>8s} {c.threads:7d} {max(case.rates):7.0f} "
            f"{np.median(case.rates):7.0f}"
        )

    # Observation cost on the calling thread: world_frames copied per environment and one
    # vectorised body-state pass (ArenaEnv.body_states), then one observation() call for all.
    default = EnvConfig(num_envs=NUM_ENVS)
    with ArenaEnv(default, rng) as made:
        made.reset(np.arange(NUM_ENVS), reference)
        states = made.body_states()
        timings = {
            f"body states ({NUM_ENVS} environments)": made.body_states,
            f"observation() on ({NUM_ENVS}, 2)": lambda: observation(states, states[:, ::-1]),
        }
        spent = {}
        for name, fn in timings.items():
            seconds = []
            for _ in range(20):
                start = time.perf_counter()
                fn()
                seconds.append(time.perf_counter() - start)
            spent[name] = min(seconds)
            print(f"{name:34s} {1e3 * spent[name]:8.2f} ms per policy step")

    def best(what: str, config: EnvConfig) -> float:
        return next(max(c.rates) for c in cases if c.what == what and c.config == config)

    one_thread = NUM_ENVS / best(f"raw physics, {default.stepping}", replace(default, threads=1))
    print(
        f"{'observations / raw physics':34s} {sum(spent.values()) / one_thread:8.0%} "
        f"(raw physics on 1 thread: {1e3 * one_thread:.1f} ms per policy step)"
    )
    chosen = best(f"raw physics, {default.stepping}", default)
    print(f"physics_steps_per_s: {chosen:.0f} steps/s")


if __name__ == "__main__":
    main()
