"""An opponent folder's ONNX policy: loaded with onnxruntime and checked against its kind.

Every kind's policy file is an ONNX model with an input "observation" (B, D) float32, D the
kind's observation size, [an input "task" (B, 2) for a heading policy] and an output "action"
(B, 28). `load_policy` refuses, in one line naming the file, a model onnxruntime cannot load or
one whose sizes are not its kind's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnxruntime

from models.humanoid.kinematics import NUM_ACTUATED
from tasks.errors import BadInput


@dataclass(frozen=True, eq=False)
class PolicyFile:
    """A loaded policy file: its onnxruntime session and its sizes."""

    path: Path
    session: onnxruntime.InferenceSession
    observation_dim: int
    task_dim: int  # 2 for a heading policy, else 0

    def run(self, observation: np.ndarray, task: np.ndarray | None = None) -> np.ndarray:
        """Actions (B, 28) float64 (for MuJoCo) for observations (B, D) [and tasks (B, 2)]."""
        obs = np.asarray(observation, dtype=np.float32)
        if obs.ndim != 2 or obs.shape[1] != self.observation_dim:
            raise ValueError(
                f"observation must have shape (B, {self.observation_dim}), got {obs.shape}"
            )
        feeds = {"observation": obs}
        if self.task_dim:
            if task is None:
                raise ValueError(f"this opponent's policy needs a task input (B, {self.task_dim})")
            feeds["task"] = np.asarray(task, dtype=np.float32)
        (actions,) = self.session.run(["action"], feeds)
        return actions.astype(np.float64)


def load_policy(path: Path, observation_dim: int, *, made_by: str) -> PolicyFile:
    """The ONNX policy at ``path``, which must take (B, ``observation_dim``) observations and give
    (B, 28) actions; ``made_by`` names what makes such observations, for the refusal."""
    try:
        session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    except Exception as error:  # onnxruntime raises its own Fail/InvalidGraph types
        raise BadInput(str(path), f"onnxruntime cannot load it ({error})") from error
    inputs = {i.name: i.shape for i in session.get_inputs()}
    outputs = {o.name: o.shape for o in session.get_outputs()}
    if "observation" not in inputs or inputs["observation"][-1] != observation_dim:
        raise BadInput(
            str(path),
            f"takes observations of shape {inputs.get('observation')}; this Ringside makes "
            f"(B, {observation_dim}) ({made_by}), so the policy belongs to another version "
            "or another kind",
        )
    if "action" not in outputs or outputs["action"][-1] != NUM_ACTUATED:
        raise BadInput(
            str(path),
            f"gives actions of shape {outputs.get('action')}; the humanoid takes {NUM_ACTUATED}",
        )
    task_dim = int(inputs["task"][-1]) if "task" in inputs else 0
    return PolicyFile(Path(path), session, observation_dim, task_dim)
