"""A tracker trained in bouts (`TrackConfig.bouts`): both fighters of an arena start standing
still in their guards, and each tracks what its motion matcher picks from its own footage against
the other (`models.tracking.matched.MatchedTracker`), the reference a matched opponent tracks
in a bout. DReCon (Bergamin et al., ACM TOG 38(6), 2019) trains its tracker on its matcher's
output so: the transitions, the starts from rest and a partner that moves are what it must
survive there, and a tracker trained on whole clips from their own states does not (a tracker
near its gate on footage fell 42 times a minute from a bout's standing start, docs/opponent.md).

- A start: a frame of the footage drawn uniformly from the matcher's candidates gives where
  both fighters stand and which way they face (as filmed: their distance and bearings are the
  footage's), each at rest in its guard (`guard_pose` of its footage), moved down or up onto
  the floor. Each fighter's matcher then searches from its body and its partner's.
- A step: each fighter's PD targets are its reference's plus the policy's correction (DReCon);
  the reference moves on; the physics steps (pushed as `Tracker.step` pushes, with
  `TrackConfig.push_every_s`); DeepMimic's reward and the errors are taken against the frame
  just reached; then each matcher searches where due, from the bodies the step left.
- An episode ends terminally on a fall or a drift (`TrackConfig.root_limit_m`: the matcher
  anchors its motion within `MatchConfig.anchor_m` of the body, so a drift is rare), and on a
  time-out at the arena's episode length (`EnvConfig.episode_s`).

Its input and output are the footage tracker's (451 inputs, 28 corrections), so a footage
tracker trains on in bouts (`train.warm_from`) and a bout tracker exports as a matched
opponent. The gate still judges it on the footage as filmed (`models.tracking.gate`).

Shape letters: N environments, n of them, 2 agents.
"""

from __future__ import annotations

import numpy as np

from models.arena.config import EnvConfig
from models.arena.controller import Seen
from models.arena.env import ArenaEnv, StepResult, to_host
from models.arena.mjcf import NUM_AGENTS
from models.arena.starts import standing_like
from models.humanoid.kinematics import NUM_ACTUATED, NV
from models.humanoid.observations import BodyState, self_observation, stacked
from models.humanoid.stance import guard_pose
from models.tracking.clips import TrackingData
from models.tracking.config import TrackConfig
from models.tracking.matched import MatchedTracker
from models.tracking.matching import motion_database
from models.tracking.reward import centre_of_mass
from models.tracking.task import (
    TRACK_OBSERVATION_DIM,
    TrackStep,
    check_corrections,
    check_rate,
    judged,
    pushed_agents,
    training_pushes,
)


class BoutTracker:
    """Tracking episodes of N arenas played as bouts (module docstring); the interface of
    `models.tracking.task.Tracker` that training uses (`reset`, `step`, `state`,
    `load_state`)."""

    def __init__(
        self,
        data: TrackingData,
        config: TrackConfig,
        env: EnvConfig,
        *,
        pushes: np.random.Generator | None = None,
    ):
        check_rate(data, env)
        lengths = [[c.num_frames for c in clips] for clips in data.clips]
        if lengths[0] != lengths[1]:
            raise ValueError(
                f"train.track.bouts: the fighters' clips of {data.key!r} do not pair up clip "
                "for clip (equal lengths), so their matchers have no partner to match"
            )
        self.config = config
        # The matcher's default settings, which `ringside export --matched` writes too.
        databases = [
            motion_database(data.clips[a], data.clips[1 - a], fps=data.fps)
            for a in range(NUM_AGENTS)
        ]
        self.players = tuple(MatchedTracker(None, db) for db in databases)
        self.guards = np.stack(
            [
                guard_pose(data.bones[a], np.concatenate([c.qpos for c in data.clips[a]]))
                for a in range(NUM_AGENTS)
            ]
        )
        self.pushes = pushes if config.push_every_s > 0 else None
        n = env.num_envs
        # What each agent tracks next (its reference's states and PD targets), set by the
        # searches after a reset or a step.
        self.ref = stacked([db.library.clip.states[np.zeros(n, dtype=int)] for db in databases])
        self.held = np.zeros((n, NUM_AGENTS, NUM_ACTUATED))

    def state(self) -> dict:
        return {
            "players": [p.state() for p in self.players],
            "ref": [
                x.copy() for x in (self.ref.pos, self.ref.rot, self.ref.lin_vel, self.ref.ang_vel)
            ],
            "held": self.held.copy(),
            "pushes": None if self.pushes is None else self.pushes.bit_generator.state,
        }

    def load_state(self, state: dict) -> None:
        for player, saved in zip(self.players, state["players"], strict=True):
            player.load_state(saved)
        self.ref = BodyState(*(np.array(x) for x in state["ref"]))
        self.held[:] = state["held"]
        if self.pushes is not None and state.get("pushes") is not None:
            self.pushes.bit_generator.state = state["pushes"]

    def _aim(self, sim: BodyState, ids: np.ndarray, own: np.ndarray | None = None) -> np.ndarray:
        """Each matcher's searches due in environments ``ids`` from bodies ``sim`` (n, 2); keeps
        what they track next and returns the observations (n, 2, 451)."""
        empty = np.zeros((len(ids), 0))
        given = []
        for a, player in enumerate(self.players):
            aim = player.target(Seen(ids, a, sim, empty, empty))
            for field in ("pos", "rot", "lin_vel", "ang_vel"):
                getattr(self.ref, field)[ids, a] = getattr(aim.states, field)
            self.held[ids, a] = aim.actions
            given.append(aim.given)
        own = self_observation(sim) if own is None else own
        return np.concatenate([own, np.stack(given, 1)], -1)

    def reset(self, env: ArenaEnv, ids: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Start environments ``ids`` (n,) as bouts (module docstring); their observations
        (n, 2, 451)."""
        ids = np.asarray(ids, dtype=int)
        candidates = self.players[0].database.candidates
        frame = candidates[rng.integers(len(candidates), size=len(ids))]
        qpos = np.stack(
            [
                standing_like(p.database.library.clip.qpos[frame], self.guards[a])
                for a, p in enumerate(self.players)
            ],
            1,
        )
        env.set_states(ids, qpos, np.zeros((len(ids), NUM_AGENTS, NV)), ground=True)
        sim = env.body_states(ids)
        empty = np.zeros((len(ids), 0))
        for a, player in enumerate(self.players):
            player.reset(Seen(ids, a, sim, empty, empty))
        return self._aim(sim, ids)

    def step(self, env: ArenaEnv, corrections: np.ndarray) -> TrackStep:
        """One policy step of every environment (module docstring)."""
        check_corrections(env, corrections)
        everyone = np.arange(env.num_envs)
        pushes = training_pushes(env, self.config, self.pushes)
        result: StepResult = env.step(self.held + corrections, pushes=pushes, opponent=False)
        for player in self.players:
            player.advance(everyone)
        body = result.body
        sim = BodyState(*(to_host(x) for x in (body.pos, body.rot, body.lin_vel, body.ang_vel)))
        clips = [p.database.library.clip for p in self.players]
        sim_com, ref_com = (
            np.stack(
                [centre_of_mass(s[:, a], c.body_mass, c.body_com) for a, c in enumerate(clips)], 1
            )
            for s in (sim, self.ref)
        )
        # Judged against the frames just reached, before the searches lay the next ones in
        # `self.ref`; the stable arenas' observations are then filled in.
        scored = judged(
            result,
            sim,
            self.ref,
            sim_com,
            ref_com,
            np.zeros((env.num_envs, NUM_AGENTS, TRACK_OBSERVATION_DIM)),
            config=self.config,
            pushed=pushed_agents(env, pushes),
        )
        live = np.flatnonzero(~result.unstable)
        if len(live):
            own = to_host(result.self_observation)
            scored.observation[live] = self._aim(sim[live], live, own[live])
        return scored
