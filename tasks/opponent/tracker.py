"""The motion tracker playing a reference clip, as a controller.

A tracker's policy (`models.tracking.task`, trained with `train.objective` 'track') sees the
fighter's own o^self and the next frame of the clip it follows (`tracking_input`, 451 numbers
in all) and gives a correction added to that frame's PD targets (DReCon), as `Tracker.actions`
does in training. `ClipTracker` plays one clip so:

- At an episode start (`reset`) the clip is laid where the fighter stands: turned about the
  vertical and moved along the floor so that its first frame's pelvis is on the fighter's and
  faces its way (heights as filmed). The fighter is then at the clip's first frame; the bout's
  start pose is the folder's guard (`tasks.opponent.export.export_tracker` writes the clip's
  first frame's hinges there), so it starts in the clip's first pose, at rest.
- Each step it tracks the clip's next frame and moves on to it: one frame per policy step (the
  clip is at the policy's rate, which the folder's loader checks).
- After the clip's last frame it holds that frame: it keeps tracking the last pose where the clip
  left it, as the training's clips end on a time-out rather than on a jump back to the start.

The folder of kind "tracker" (`tasks.opponent.folder`): policy.onnx, input "observation"
(B, 451) float32, output "action" (B, 28), the correction (the tracker's normaliser and mean);
clip.npz, the clip as played: "qpos" (T, 35) of the fighter on its bones, "fps" and "name".

Shape letters: B arenas given, T frames of the clip.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from models.arena.controller import Seen
from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import NQ
from models.humanoid.observations import BodyState, self_observation
from models.tracking.clips import ReferenceClip, reference_clip
from models.tracking.matched import laid, laying
from models.tracking.task import TRACK_OBSERVATION_DIM, tracking_input
from tasks.errors import BadInput
from tasks.opponent.policy_file import PolicyFile, load_policy

KIND = "tracker"
CLIP = "clip.npz"
FILES = ("policy.onnx", CLIP, "humanoid.xml", "arena.xml")


class ClipTracker:
    """A tracker's policy playing ``clip`` (module docstring).

    Args:
        policy: (B, 451) float32 tracker observations -> (B, 28) float64 corrections, e.g. an
            exported tracker's `PolicyFile.run`.
        clip: the clip to play, on the fighter's bones, at the policy's rate.
    """

    def __init__(self, policy: Callable[[np.ndarray], np.ndarray], clip: ReferenceClip):
        self.policy, self.clip = policy, clip
        self.last = clip.num_frames - 1
        self._frame = np.zeros(0, dtype=int)  # by arena: the clip frame the fighter is at; -1: none
        self._turn = np.zeros((0, 3, 3))  # by arena: the clip's rotation about the vertical
        self._shift = np.zeros((0, 3))  # by arena: then its move along the floor

    def _grow(self, count: int) -> None:
        extra = count - len(self._frame)
        if extra > 0:
            self._frame = np.concatenate([self._frame, np.full(extra, -1)])
            self._turn = np.concatenate([self._turn, np.tile(np.eye(3), (extra, 1, 1))])
            self._shift = np.concatenate([self._shift, np.zeros((extra, 3))])

    def fresh(self) -> ClipTracker:
        return ClipTracker(self.policy, self.clip)

    def reset(self, seen: Seen) -> None:
        ids = np.asarray(seen.arenas, dtype=int)
        self._grow(int(ids.max()) + 1 if len(ids) else 0)
        turn, shift = laying(seen.body, self.clip.states[np.zeros(len(ids), dtype=int)])
        self._frame[ids] = 0
        self._turn[ids] = turn
        self._shift[ids] = shift

    def reference(self, frames: np.ndarray, arenas: np.ndarray) -> BodyState:
        """(B,) the clip's frames ``frames`` (B,) where it was laid in ``arenas`` (B,)."""
        return laid(self.clip.states[frames], self._turn[arenas], self._shift[arenas])

    def frames(self, arenas: np.ndarray) -> np.ndarray:
        """(B,) the clip frame the fighter is at in each of ``arenas``."""
        return self._frame[np.asarray(arenas, dtype=int)].copy()

    def act(self, seen: Seen) -> np.ndarray:
        ids = np.asarray(seen.arenas, dtype=int)
        if len(ids) and (ids.max() >= len(self._frame) or (self._frame[ids] < 0).any()):
            raise ValueError("act before reset: every arena's episode starts with `reset`")
        nxt = np.minimum(self._frame[ids] + 1, self.last)
        sim = seen.body
        given = tracking_input(sim, self.reference(nxt, ids), self.clip.observation[nxt])
        correction = self.policy(np.concatenate([self_observation(sim), given], -1))
        self._frame[ids] = nxt
        return self.clip.actions[nxt] + correction


def clip_file(name: str, qpos: np.ndarray, fps: float) -> dict[str, np.ndarray]:
    """The arrays of clip.npz (module docstring)."""
    return {
        "qpos": np.asarray(qpos, dtype=np.float64),
        "fps": np.float64(fps),
        "name": np.str_(name),
    }


def load_clip(path: Path, bones: BoneLengths, *, policy_hz: float) -> ReferenceClip:
    """clip.npz as a ReferenceClip on ``bones``; BadInput naming the file otherwise."""
    try:
        with np.load(path, allow_pickle=False) as stored:
            qpos, fps, name = stored["qpos"], float(stored["fps"]), str(stored["name"])
    except (OSError, ValueError, KeyError) as error:
        raise BadInput(str(path), f"not a clip file with qpos, fps and name ({error})") from error
    if fps != policy_hz:
        raise BadInput(
            str(path),
            f"a clip at {fps:g} fps; the policy steps at {policy_hz:g} Hz, a frame a step",
        )
    if qpos.ndim != 2 or qpos.shape[1] != NQ:
        raise BadInput(str(path), f"qpos must be (T, {NQ}), got {qpos.shape}")
    try:
        return reference_clip(name, qpos, bones, fps=fps)
    except ValueError as error:
        raise BadInput(str(path), str(error)) from error


def tracker_policy(folder: Path, manifest: dict) -> tuple[PolicyFile, float]:
    """A folder's tracker policy (451 inputs, no task) and the rate it steps at (the manifest's
    env.policy_hz); BadInput naming the file otherwise. Also the "matched" kind's."""
    policy = load_policy(
        folder / "policy.onnx",
        TRACK_OBSERVATION_DIM,
        made_by="the motion tracker's o^self and tracking_input",
    )
    if policy.task_dim:
        raise BadInput(str(policy.path), "a tracker's policy takes no task input")
    try:
        policy_hz = float(manifest["env"]["policy_hz"])
    except (KeyError, TypeError, ValueError) as error:
        raise BadInput(
            str(folder / "manifest.json"), f"env.policy_hz unreadable ({error})"
        ) from error
    return policy, policy_hz


def load(
    folder: Path, manifest: dict, bones: tuple[BoneLengths, BoneLengths], agent: int
) -> ClipTracker:
    """The controller of a "tracker" folder (files checked by the caller)."""
    policy, policy_hz = tracker_policy(folder, manifest)
    clip = load_clip(folder / CLIP, bones[agent], policy_hz=policy_hz)
    return ClipTracker(policy.run, clip)
