"""MAAIP's policy as a controller: the fighter acts on its policy's mean (MAAIP §4.2).

Two of them, one policy on either side of the export: `OnnxPolicy`, an opponent folder's
policy.onnx run by onnxruntime (what `spar` and `spar-server` run, without torch), and
`TorchPolicy`, a trained run's torch policy (what the evaluation's bouts run). Both act on the
fighter's observation (B, 274) as float32 [and its heading task input], nothing else of `Seen`,
and keep nothing between steps.

The folder of kind "maaip" (`tasks.opponent.folder`): policy.onnx, input "observation"
(B, 274) float32 [+ "task" (B, 2) for a heading policy], output "action" (B, 28), the
observation normaliser and the Gaussian's mean of one agent (the exploration noise is left out:
the opponent acts on its mean).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from models.arena.controller import Seen
from models.humanoid.boxer import BoneLengths
from models.humanoid.observations import OBSERVATION_DIM
from tasks.opponent.policy_file import PolicyFile, load_policy

if TYPE_CHECKING:
    from models.maaip.networks import Policy

KIND = "maaip"
FILES = ("policy.onnx", "humanoid.xml", "arena.xml")


@dataclass(frozen=True, eq=False)
class OnnxPolicy:
    """An exported MAAIP policy (module docstring)."""

    policy: PolicyFile

    @property
    def task_dim(self) -> int:
        return self.policy.task_dim

    def actions(self, observation: np.ndarray, task: np.ndarray | None = None) -> np.ndarray:
        """(B, 28) for observations (B, 274) [and task inputs (B, 2)] of this agent."""
        return self.policy.run(observation, task)

    def reset(self, seen: Seen) -> None:
        pass

    def act(self, seen: Seen) -> np.ndarray:
        return self.policy.run(seen.observation, seen.task)

    def fresh(self) -> OnnxPolicy:
        return self


@dataclass(frozen=True, eq=False)
class TorchPolicy:
    """Agent ``agent``'s deterministic policy: the mean action, from float32 inputs as in
    training."""

    policy: Policy
    agent: int

    def __post_init__(self) -> None:
        if self.agent not in (0, 1):
            raise ValueError(f"agent must be 0 or 1, got {self.agent!r}")

    def reset(self, seen: Seen) -> None:
        pass

    def act(self, seen: Seen) -> np.ndarray:
        # Imported here: the folder's kinds are loaded without torch (`spar` runs on
        # onnxruntime alone), and only a torch policy's caller has it already.
        import torch

        obs = torch.from_numpy(np.asarray(seen.observation, dtype=np.float32))
        task = seen.task
        given = None if task is None else torch.from_numpy(np.asarray(task, dtype=np.float32))
        with torch.no_grad():
            return self.policy(obs, self.agent, given).double().numpy()

    def fresh(self) -> TorchPolicy:
        return self


def load(
    folder: Path, manifest: dict, bones: tuple[BoneLengths, BoneLengths], agent: int
) -> OnnxPolicy:
    """The controller of a "maaip" folder (files checked by the caller)."""
    return OnnxPolicy(load_policy(folder / "policy.onnx", OBSERVATION_DIM, made_by="MAAIP §4.2"))
