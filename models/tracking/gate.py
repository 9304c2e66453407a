"""The tracker's gate: every clip of both agents tracked from its first frame to its end on a
policy's mean, in an arena of its own, and the figures that judge it (finished share, body and
root errors, `models.tracking.reward`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol

import mujoco
import numpy as np
import torch
from torch import Tensor

from models.arena.config import EnvConfig
from models.arena.env import ArenaEnv
from models.arena.mjcf import NUM_AGENTS
from models.tracking.clips import TrackingData
from models.tracking.config import TrackConfig
from models.tracking.task import Tracker


class TrackingPolicy(Protocol):
    """A tracker's policy (MAAIP's `Policy` on the tracker's observation): its mean correction
    (B, 28) for observations (B, 451) of agents (B,)."""

    def act(
        self, obs: Tensor, agent: Tensor, *, deterministic: bool = False
    ) -> tuple[Tensor, Tensor]: ...

    def parameters(self) -> Iterator[torch.nn.Parameter]: ...


class TrackingRun(Protocol):
    """What of a run's settings the gate plays with: the arena's physics and the tracking's."""

    @property
    def env(self) -> EnvConfig: ...

    @property
    def track(self) -> TrackConfig: ...


@dataclass(frozen=True)
class GateRow:
    """One clip tracked by one agent from its first frame, acting on the policy's mean.

    Attributes:
        agent, clip: who tracked which clip (its name).
        finished: it reached the clip's last frame without a fall or a drift.
        frames: the steps it tracked (the terminating one included).
        body_error_cm, root_error_cm: mean errors over those steps.
    """

    agent: int
    clip: str
    finished: bool
    frames: int
    body_error_cm: float
    root_error_cm: float


@dataclass(frozen=True)
class Gate:
    """`track_gate`'s figures: the share of runs finished (%), and the mean over runs of each
    run's mean body and root errors (cm); `rows` per run."""

    finished_pct: float
    body_error_cm: float
    root_error_cm: float
    rows: tuple[GateRow, ...]


@dataclass(frozen=True, eq=False)
class Played:
    """`play_clips`' outcome.

    Attributes:
        rows: one per agent and clip, agent by agent.
        qpos: (S, n, nq) the arena's qpos after each step, environment k playing each agent's
            clip k; an agent's run is its first ``frames`` steps (`GateRow.frames`).
        body_error: (S, n, 2) each agent's body error after each step (m; NaN where the
            step's judgement had none), meaningful over its run as ``qpos`` is.
        model: the arena's model (the humanoids' prefixes `models.arena.mjcf.DEFAULT_PREFIXES`).
    """

    rows: tuple[GateRow, ...]
    qpos: np.ndarray
    body_error: np.ndarray
    model: mujoco.MjModel


def play_clips(
    policy: TrackingPolicy, data: TrackingData, config: TrackingRun, *, as_filmed: bool = False
) -> Played:
    """Track every clip of both agents from its first frame to its end, acting on ``policy``'s
    mean, in an arena of its own (the trainer's environments and random state are untouched).

    Environment k has each agent on its clip k (the last clip again where an agent has fewer),
    at its slot or, ``as_filmed``, where the footage has them (`Tracker.reset`); a run ends at
    the clip's last frame (finished) or at its agent's fall or drift.
    """
    counts = [len(c) for c in data.clips]
    n = max(counts)
    # The training arena's physics; episodes long enough for any clip.
    env_config = dataclasses.replace(config.env, num_envs=n, episode_s=3600.0)
    device = next(policy.parameters()).device
    rows: list[GateRow] = []
    played: list[np.ndarray] = []
    errors: list[np.ndarray] = []
    with ArenaEnv(env_config, np.random.default_rng(0), data.bones, str(device)) as env:
        tracker = Tracker(data, config.track, env_config)
        clips = np.stack([np.minimum(np.arange(n), c - 1) for c in counts], 1)
        last = np.array(
            [[data.clips[a][k].num_frames - 1 for a, k in enumerate(row)] for row in clips]
        )
        obs = tracker.reset(
            env, np.arange(n), np.random.default_rng(0), clips=clips, as_filmed=as_filmed
        )
        agent_ids = torch.arange(NUM_AGENTS, device=device).repeat(n)
        alive = np.ones((n, NUM_AGENTS), dtype=bool)
        finished = np.zeros((n, NUM_AGENTS), dtype=bool)
        steps = np.zeros((n, NUM_AGENTS), dtype=int)
        body, root = np.zeros((n, NUM_AGENTS)), np.zeros((n, NUM_AGENTS))
        while alive.any():
            x = torch.as_tensor(obs, dtype=torch.float32, device=device).reshape(2 * n, -1)
            mean, _ = policy.act(x, agent_ids, deterministic=True)
            step = tracker.step(env, mean.reshape(n, NUM_AGENTS, -1).cpu().double().numpy())
            played.append(np.stack([d.qpos.copy() for d in env.datas]))
            errors.append(np.asarray(step.body_error, dtype=float).copy())
            steps += alive
            body += np.where(alive, np.nan_to_num(step.body_error, nan=1.0), 0.0)
            root += np.where(alive, np.nan_to_num(step.root_error, nan=1.0), 0.0)
            _, frame = tracker.clip_and_frame()
            at_end = frame >= last
            failed = step.terminal
            finished |= alive & at_end & ~failed
            alive &= ~(at_end | failed)
            obs = step.observation
        model = env.model
    for a in range(NUM_AGENTS):
        for k in range(counts[a]):
            rows.append(
                GateRow(
                    agent=a,
                    clip=data.clips[a][k].name,
                    finished=bool(finished[k, a]),
                    frames=int(steps[k, a]),
                    body_error_cm=float(100 * body[k, a] / steps[k, a]),
                    root_error_cm=float(100 * root[k, a] / steps[k, a]),
                )
            )
    return Played(tuple(rows), np.stack(played), np.stack(errors), model)


def gate_of(rows: Sequence[GateRow]) -> Gate:
    """The gate's figures over ``rows``."""
    return Gate(
        finished_pct=100 * float(np.mean([r.finished for r in rows])),
        body_error_cm=float(np.mean([r.body_error_cm for r in rows])),
        root_error_cm=float(np.mean([r.root_error_cm for r in rows])),
        rows=tuple(rows),
    )


def gate_met(gate: Gate, config: TrackConfig) -> bool:
    """Whether one check meets the gate: enough clips finished, both errors small enough."""
    return (
        gate.finished_pct >= config.gate_finished_pct
        and gate.body_error_cm <= config.gate_body_error_cm
        and gate.root_error_cm <= config.gate_root_error_cm
    )


def gate_held(met: Sequence[bool], config: TrackConfig) -> bool:
    """Whether a run's checks so far, oldest first, hold the gate: met in at least
    `gate_needed` of the last `gate_window` (one check that touches it is not enough: the
    punch's last frames flip in and out)."""
    return sum(bool(m) for m in met[-config.gate_window :]) >= config.gate_needed


def track_gate(
    policy: TrackingPolicy,
    data: TrackingData,
    config: TrackingRun,
    *,
    agents: Sequence[int] = (0, 1),
) -> Gate:
    """`play_clips` at the agents' slots, judged over the runs of ``agents``."""
    played = play_clips(policy, data, config)
    return gate_of([r for r in played.rows if r.agent in agents])
