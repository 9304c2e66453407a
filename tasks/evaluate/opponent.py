"""An exported opponent: one folder that other software can load and run without torch.

The folder (`tasks.evaluate.export.export_opponent` writes it):

================  ===============================================================================
policy.onnx       the agent's policy: its observation normaliser and the Gaussian's mean, input
                  "observation" (B, 274) float32 [+ "task" (B, 2) for a heading policy], output
                  "action" (B, 28), the PD targets' actions (MAAIP §4.2; the exploration noise
                  is left out: the opponent acts on its mean)
humanoid.xml      the fighter's MuJoCo model, with its measured bones
arena.xml         both fighters facing each other on a floor, as the policy was trained in
manifest.json     what the files are (SHA-256 each), the observation and action layouts, the
                  rates, the bones, each fighter's guard (the 28 hinge angles its policy's mean
                  starts from, a pose it holds unaided), the dataset and training keys and the
                  run's last metrics
================  ===============================================================================

This module reads the folder with onnxruntime and numpy only, so a sparring engine needs
neither torch nor a GPU.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnxruntime

from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import NUM_ACTUATED
from models.humanoid.observations import OBSERVATION_DIM
from storage.files import sha256_file
from tasks.errors import BadInput

FORMAT = 1
FILES = ("policy.onnx", "humanoid.xml", "arena.xml")
MANIFEST = "manifest.json"


@dataclass(frozen=True, eq=False)
class Opponent:
    """A loaded opponent folder.

    Attributes:
        folder: where it was loaded from.
        manifest: the parsed manifest.json.
        session: the onnxruntime session of policy.onnx.
        agent: which of the training run's agents it is (0: the adversary).
        bones: both fighters' bones as trained (agent 0's, then agent 1's).
        task_dim: extra policy inputs (2 for a heading policy, else 0).
        guard: (2, 28) both fighters' guards, the hinge angles they start a bout in (the rest
            pose, all zeros, for a folder written before guards were exported).
    """

    folder: Path
    manifest: dict
    session: onnxruntime.InferenceSession
    agent: int
    bones: tuple[BoneLengths, BoneLengths]
    task_dim: int
    guard: np.ndarray

    def act(self, observation: np.ndarray, task: np.ndarray | None = None) -> np.ndarray:
        """Actions (B, 28) for observations (B, 274) of this agent (float64 out for MuJoCo)."""
        obs = np.asarray(observation, dtype=np.float32)
        if obs.ndim != 2 or obs.shape[1] != OBSERVATION_DIM:
            raise ValueError(f"observation must have shape (B, {OBSERVATION_DIM}), got {obs.shape}")
        feeds = {"observation": obs}
        if self.task_dim:
            if task is None:
                raise ValueError(f"this opponent's policy needs a task input (B, {self.task_dim})")
            feeds["task"] = np.asarray(task, dtype=np.float32)
        (actions,) = self.session.run(["action"], feeds)
        return actions.astype(np.float64)


def load_opponent(folder: Path) -> Opponent:
    """Load and check an opponent folder; BadInput naming the file and the problem otherwise."""
    folder = Path(folder)
    if not folder.is_dir():
        raise BadInput(str(folder), "no such opponent folder (make one with `ringside export`)")
    manifest_path = folder / MANIFEST
    if not manifest_path.is_file():
        raise BadInput(str(manifest_path), "missing: not an opponent folder")
    try:
        manifest = json.loads(manifest_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise BadInput(str(manifest_path), f"not valid JSON ({error})") from error
    if manifest.get("format") != FORMAT:
        raise BadInput(
            str(manifest_path),
            f"format {manifest.get('format')!r}; this Ringside reads format {FORMAT}",
        )
    digests = manifest.get("files", {})
    for name in FILES:
        path = folder / name
        if not path.is_file():
            raise BadInput(str(path), "missing from the opponent folder")
        if name not in digests:
            raise BadInput(str(manifest_path), f"lists no SHA-256 for {name}")
        if sha256_file(path) != digests[name]:
            raise BadInput(
                str(path), "does not match the manifest's SHA-256 (changed or from another export)"
            )
    policy_path = folder / "policy.onnx"
    try:
        session = onnxruntime.InferenceSession(str(policy_path), providers=["CPUExecutionProvider"])
    except Exception as error:  # onnxruntime raises its own Fail/InvalidGraph types
        raise BadInput(str(policy_path), f"onnxruntime cannot load it ({error})") from error
    inputs = {i.name: i.shape for i in session.get_inputs()}
    outputs = {o.name: o.shape for o in session.get_outputs()}
    if "observation" not in inputs or inputs["observation"][-1] != OBSERVATION_DIM:
        raise BadInput(
            str(policy_path),
            f"takes observations of shape {inputs.get('observation')}; this Ringside makes "
            f"(B, {OBSERVATION_DIM}) (MAAIP §4.2), so the policy belongs to another version",
        )
    if "action" not in outputs or outputs["action"][-1] != NUM_ACTUATED:
        raise BadInput(
            str(policy_path),
            f"gives actions of shape {outputs.get('action')}; the humanoid takes {NUM_ACTUATED}",
        )
    task_dim = int(inputs["task"][-1]) if "task" in inputs else 0
    try:
        bones = tuple(BoneLengths(**b) for b in manifest["bones"])
        agent = int(manifest["agent"])
    except (KeyError, TypeError, ValueError) as error:
        raise BadInput(str(manifest_path), f"bones or agent unreadable ({error})") from error
    if len(bones) != 2 or agent not in (0, 1):
        raise BadInput(str(manifest_path), "needs two fighters' bones and an agent of 0 or 1")
    try:
        guard = np.asarray(manifest.get("guard", np.zeros((2, NUM_ACTUATED))), dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise BadInput(str(manifest_path), f"guard unreadable ({error})") from error
    if guard.shape != (2, NUM_ACTUATED) or not np.isfinite(guard).all():
        raise BadInput(
            str(manifest_path), f"guard must be 2 x {NUM_ACTUATED} finite angles, got {guard.shape}"
        )
    return Opponent(folder, manifest, session, agent, bones, task_dim, guard)
