"""Contacts into damage and floor touches (`models.arena.env` says what counts), read two ways.

- From `MjData.contact` after each `mujoco.mj_step` ("threads" stepping): `contact_tables` says
  once per model what a contact between two geoms means, and `read_contacts` adds one
  substep's damage (`mujoco.mj_contactForce`'s normal force) and floor touches.
- From the arena's contact sensors (`arena_mjcf(contact_sensors=True)`), whose values
  `mujoco.rollout` and MuJoCo Warp return after each substep ("rollout", "warp"):
  `sensor_contacts`, for NumPy arrays or torch tensors on Warp's device.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from array_api_compat import array_namespace

from models.arena.mjcf import DAMAGE_SENSOR_SLOTS, NUM_AGENTS, ArenaIndex, SensorLayout


@dataclass(frozen=True, eq=False)
class ContactTables:
    """Per-pair lookups for reading contacts fast: pair_kind[g1, g2] says what a contact
    between geoms g1 and g2 means (0: nothing to record)."""

    # (ngeom, ngeom) int: bit a (1 << a) if the pair damages agent a, bit 2 + a if agent a
    # touches the floor with a geom other than its feet and shins.
    pair_kind: np.ndarray


def contact_tables(model: mujoco.MjModel, index: ArenaIndex) -> ContactTables:
    ngeom = model.ngeom
    kind = np.zeros((ngeom, ngeom), dtype=np.int64)
    target = np.full(ngeom, -1)
    for a in range(NUM_AGENTS):
        target[index.damage_geoms[a]] = a
    owner = index.agent_of_geom
    grounded = np.zeros(ngeom, dtype=bool)
    grounded[index.grounded_geoms.ravel()] = True
    for g1 in range(ngeom):
        for g2 in range(ngeom):
            bits = 0
            if owner[g1] >= 0 and owner[g2] >= 0 and owner[g1] != owner[g2]:
                for g, other in ((g1, g2), (g2, g1)):
                    if target[g] >= 0 and owner[other] == 1 - target[g]:
                        bits |= 1 << int(target[g])
            for floor, body in ((g1, g2), (g2, g1)):
                if floor == index.floor_geom and owner[body] >= 0 and not grounded[body]:
                    bits |= 1 << (2 + int(owner[body]))
            kind[g1, g2] = bits
    kind.setflags(write=False)
    return ContactTables(kind)


def read_contacts(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    tables: ContactTables,
    damage: np.ndarray,
    floor: np.ndarray,
    force: np.ndarray,
) -> None:
    """Add this substep's damage (2,) and floor touches (2,) of one environment in place.

    `data` is right after `mj_step`: its contacts and constraint forces are those the step
    computed (at the state before its integration).
    """
    if data.ncon == 0:
        return
    geom = data.contact.geom
    kinds = tables.pair_kind[geom[:, 0], geom[:, 1]]
    for c in np.flatnonzero(kinds):
        bits = int(kinds[c])
        if bits & 3:
            mujoco.mj_contactForce(model, data, int(c), force)
            for a in range(NUM_AGENTS):
                if bits & (1 << a):
                    damage[a] += force[0]
        for a in range(NUM_AGENTS):
            if bits & (1 << (2 + a)):
                floor[a] = True


def sensor_contacts(sensordata: np.ndarray, layout: SensorLayout) -> tuple[np.ndarray, np.ndarray]:
    """Damage and floor touches from the arena's contact sensors, summed over substeps.

    Args:
        sensordata: (N, S, nsensordata) sensor values after each of S substeps (`mujoco.rollout`;
            a NumPy array, or a torch tensor on Warp's device, which gives tensors back).
        layout: from `arena_index` of a model built with contact_sensors=True.

    Returns:
        (N, 2) damage in newtons and (N, 2) bool floor touches by a geom other than the
        feet and shins.
    """
    xp = array_namespace(sensordata)
    width = 4  # found, then the force in the contact frame (normal first)
    damage, floor = [], []
    for a in range(NUM_AGENTS):
        total = 0.0
        for start in layout.damage[a]:
            slots = sensordata[..., start : start + DAMAGE_SENSOR_SLOTS * width]
            slots = xp.reshape(slots, (*slots.shape[:-1], DAMAGE_SENSOR_SLOTS, width))
            found = xp.where(slots[..., 0] > 0, slots[..., 1], xp.zeros_like(slots[..., 1]))
            total = total + xp.sum(found, axis=(1, 2))
        grounded = xp.sum(sensordata[..., list(layout.grounded[a])], axis=-1)
        damage.append(total)
        floor.append(xp.any(sensordata[..., layout.floor[a]] - grounded > 0, axis=1))
    return xp.stack(damage, axis=1), xp.stack(floor, axis=1)
