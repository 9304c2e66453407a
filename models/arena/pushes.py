"""Random pushes: now and then an object thrown at one of a fighter's body parts, as the forces
`ArenaEnv.step` applies (`pushes`, MuJoCo's xfrc_applied).

DReCon (Bergamin et al., ACM TOG 38(6), 2019) trains its tracker against objects of 1-10 kg
thrown at 5 m/s about once a second, so that it learns to recover rather than only to follow.
Here the object stops where it hits (an inelastic hit): its momentum m v is delivered to the
body part over one policy step, as a constant horizontal force m v / step at that body's centre
of mass, from a direction drawn uniformly around the fighter.
"""

from __future__ import annotations

import numpy as np


def random_pushes(
    rng: np.random.Generator,
    body_ids: np.ndarray,
    *,
    num_envs: int,
    nbody: int,
    chance: float,
    mass_kg: tuple[float, float],
    speed_mps: float,
    step_s: float,
) -> np.ndarray:
    """(num_envs, nbody, 6) this step's pushes: each agent of each environment is hit with
    probability ``chance``, by an object of a mass uniform in ``mass_kg`` at ``speed_mps``, at
    one of its bodies ``body_ids`` (2, B: model body ids, agent by agent) drawn uniformly
    (module docstring). The same draws are made whether or not anything is hit, so the
    generator advances alike every step."""
    agents, parts = body_ids.shape
    shape = (num_envs, agents)
    hit = rng.random(shape) < chance
    part = rng.integers(parts, size=shape)
    mass = rng.uniform(mass_kg[0], mass_kg[1], size=shape)
    yaw = rng.uniform(0.0, 2 * np.pi, size=shape)
    pushes = np.zeros((num_envs, nbody, 6))
    env, agent = np.nonzero(hit)
    force = mass[hit] * speed_mps / step_s
    body = body_ids[agent, part[hit]]
    pushes[env, body, 0] = force * np.cos(yaw[hit])
    pushes[env, body, 1] = force * np.sin(yaw[hit])
    return pushes
