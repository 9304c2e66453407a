"""Motion out for animation tools: BVH files of lifted motion and of evaluated bouts.

Two sources, one writer (`models.humanoid.bvh.bvh_text`, 30 Hz, each fighter on its own
humanoid):
- a video's lift output: each fighter's cleaned motion, one file per unbroken run of lifted steps
  within a shot (a cut or a stretch the fighter was not lifted starts a new file);
- an evaluation's trained bouts, which the evaluate stage stores as `BOUTS` (`bouts_npz`): one
  file per episode and fighter.

No torch here: exporting motion needs only NumPy, MuJoCo and the stored rows.
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from models.humanoid.boxer import BoneLengths
from models.humanoid.bvh import bvh_text
from models.humanoid.kinematics import NQ
from models.humanoid.motion import RATE, FighterMotion
from tasks.dataset.stage import cut_clips, shot_of
from tasks.roles import ROLES


@dataclass(frozen=True, eq=False)
class BvhFile:
    """One BVH document and the motion it holds (one humanoid's qpos per 30 Hz frame)."""

    text: str
    bones: BoneLengths
    qpos: np.ndarray  # (frames, 35)

    @property
    def frames(self) -> int:
        return len(self.qpos)


def _bvh(bones: BoneLengths, qpos: np.ndarray) -> BvhFile:
    return BvhFile(bvh_text(bones, qpos, RATE), bones, qpos)


# The evaluate stage's artifact holding its trained bouts (`bouts_npz`).
BOUTS = "bouts.npz"


def bouts_npz(qpos: np.ndarray, frames: np.ndarray, bones: Sequence[BoneLengths]) -> bytes:
    """The trained bouts as stored: each episode's valid arena qpos rows (float32, the episodes
    one after another), the rows per episode, and both fighters' bones (JSON)."""
    rows = np.concatenate([qpos[e, :n] for e, n in enumerate(frames)]).astype(np.float32)
    buffer = io.BytesIO()
    np.savez_compressed(
        buffer,
        qpos=rows,
        frames=np.asarray(frames, dtype=np.int64),
        bones=np.array(json.dumps([asdict(b) for b in bones])),
    )
    return buffer.getvalue()


def bout_files(data: bytes) -> dict[str, BvhFile]:
    """BVH text (at the policy's 30 Hz) per episode and fighter of stored bouts (`bouts_npz`), named
    ``bout<EE>-<role>.bvh``."""
    with np.load(io.BytesIO(data), allow_pickle=False) as stored:
        rows = stored["qpos"].astype(np.float64)
        frames = stored["frames"]
        bones = [BoneLengths(**b) for b in json.loads(str(stored["bones"]))]
    if rows.shape != (int(frames.sum()), 2 * NQ):
        raise ValueError(
            f"stored bouts hold qpos {rows.shape}, expected ({frames.sum()}, {2 * NQ})"
        )
    files = {}
    starts = np.r_[0, np.cumsum(frames)[:-1]]
    for episode, (start, count) in enumerate(zip(starts, frames, strict=True)):
        for agent, role in enumerate(ROLES):
            qpos = rows[start : start + count, agent * NQ : (agent + 1) * NQ]
            files[f"bout{episode:02d}-{role}.bvh"] = _bvh(bones[agent], qpos)
    return files


def lifted_files(
    fighters: Mapping[str, FighterMotion], shots: Sequence[tuple[int, int, int]], fps: float
) -> dict[str, BvhFile]:
    """BVH text of each fighter's lifted motion, one file per unbroken run of steps within a
    shot, named ``<role>-shot<N>-steps<first>-<end>.bvh`` (``end`` one past the last step).

    Args:
        fighters: a lift output's motion by role (`tasks.lift.store.load_motion`).
        shots: the video's shots as (shot, start_frame, end_frame).
        fps: the video's frame rate (to place the 30 Hz steps in its shots).
    """
    files = {}
    for role, motion in fighters.items():
        clips = cut_clips(
            motion.step,
            shot_of(motion.step, shots, fps),
            validation_from=int(motion.step[-1]) + 1,
            min_steps=1,
            kind="single",
            role=role,
        )
        for clip in clips:
            qpos = motion.qpos[motion.rows(clip.steps)]
            name = f"{role}-shot{clip.shot}-steps{clip.start}-{clip.end}.bvh"
            files[name] = _bvh(motion.bones, qpos)
    return files
