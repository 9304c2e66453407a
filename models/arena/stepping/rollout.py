"""Stepping "rollout" (the default): `mujoco.rollout.Rollout`, MuJoCo's own thread pool.

It takes and returns states (mjSTATE_FULLPHYSICS) and sensor values, not MjData: contacts come
from contact sensors the arena gets for it (`arena_mjcf(contact_sensors=True)`; they report the
normal forces `mj_contactForce` gives, in up to 8 contacts per target body and substep), and the
final states are copied back into the MjData, whose kinematics are then refreshed for the
observations. The solver's warm start (qacc_warmstart) is not part of the returned state, so
each call starts it cold; the trajectories agree with "threads" to the solver's tolerance
(1e-13 m over 6 steps in the tests), not bit for bit.
"""

from __future__ import annotations

import mujoco
import mujoco.rollout
import numpy as np

from models.arena.config import EnvConfig
from models.arena.contacts import sensor_contacts
from models.arena.mjcf import NUM_AGENTS
from models.arena.puppet import PuppetPaths
from models.arena.stepping.host import HostWorlds, OnHost, stable_states

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
_CTRL = mujoco.mjtState.mjSTATE_CTRL
_PUSHED = mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_XFRC_APPLIED


class RolloutStepping(OnHost):
    """The N MjData of ``worlds`` stepped by `mujoco.rollout` (module docstring)."""

    def __init__(self, worlds: HostWorlds, config: EnvConfig, device: str = "cpu"):
        super().__init__(worlds, config)
        # nthread=0 runs on the calling thread: the sequential case of the same code.
        threads = config.threads if config.threads > 1 else 0
        self._rollout: mujoco.rollout.Rollout | None = mujoco.rollout.Rollout(nthread=threads)
        self._scratch = [mujoco.MjData(self.model) for _ in range(max(threads, 1))]
        self._nstate = mujoco.mj_stateSize(self.model, _FULL)
        # Where qpos and qvel lie in a full-physics state: after the time, in that order.
        start = mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_TIME)
        self._physics = slice(start, start + self.model.nq + self.model.nv)

    def close(self) -> None:
        if self._rollout is not None:
            self._rollout.close()
            self._rollout = None

    def advance(
        self,
        ctrl: np.ndarray,
        *,
        contacts: bool,
        paths: PuppetPaths | None = None,
        pushes: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        assert self._rollout is not None, "the arena is closed"
        model, n, datas = self.model, self.config.num_envs, self.worlds.datas
        state = np.empty((n, self._nstate))
        for i, data in enumerate(datas):
            mujoco.mj_getState(model, data, state[i], _FULL)
        # A push rides in the control vector (ctrl, then xfrc_applied), so it is applied in the
        # rollout's own substeps and nowhere else.
        spec, held = _CTRL, ctrl
        if pushes is not None:
            spec, held = _PUSHED, np.concatenate([ctrl, pushes.reshape(n, -1)], axis=1)
        control = np.repeat(held[:, None, :], self.config.substeps, axis=1)
        # The returned states lack the solver's warm start, so every call starts it cold
        # (zeros), whatever the MjData hold; within the call it carries over as in mj_step.
        states, sensordata = self._rollout.rollout(
            model,
            self._scratch,
            state,
            control,
            control_spec=spec,
            initial_warmstart=np.zeros((n, model.nv)),
        )
        if pushes is not None:
            for data in self._scratch:  # a rollout without pushes must not inherit them
                data.xfrc_applied[:] = 0.0
        final = states[:, -1]
        if contacts:
            # One vectorised check of every world's qpos and qvel (per world it was 40 % of
            # gathering one, measured).
            self.worlds.stable[:] = stable_states(final[:, self._physics])
        for i, data in enumerate(datas):
            mujoco.mj_setState(model, data, final[i], _FULL)
            data.ctrl[:] = ctrl[i]
            if contacts:
                self.worlds.gather(i, check=False)
        if not contacts:
            return np.zeros((n, NUM_AGENTS)), np.zeros((n, NUM_AGENTS), dtype=bool)
        sensors = self.worlds.index.sensors
        assert sensors is not None
        return sensor_contacts(sensordata, sensors)
