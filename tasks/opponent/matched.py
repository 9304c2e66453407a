"""The opponent folder of kind "matched": the motion tracker playing the fighter's own footage,
chosen as it goes by the partner-aware motion matcher (`models.tracking.matched.MatchedTracker`,
which documents how it plays; DReCon, Bergamin et al. 2019; Vid2Player3D, Zhang et al. 2023).

The folder (`tasks.opponent.folder`): policy.onnx, the tracker's, input "observation" (B, 451)
float32, output "action" (B, 28); motion.npz, the database's clips as played: "qpos" (F, 35) of
the fighter on its bones, "partner_qpos" (F, 35) of the other fighter of the footage at the
same frames, "lengths" (C,) the clips' frame counts, "names" (C,), "fps", and where the motion
is the tracker's replay of the footage (the manifest's "motion" "source": "replay",
`tasks.opponent.export.replayed_footage`) "body_error_m" (F,), the body error of each frame as
it was played; and the matcher's settings in the manifest ("matcher", `MatchConfig.as_dict`).

Shape letters: F frames of the database, C clips.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import NQ
from models.tracking.clips import reference_clip
from models.tracking.matched import MatchedTracker
from models.tracking.matching import MatchConfig, MotionDatabase, motion_database
from tasks.errors import BadInput
from tasks.opponent.tracker import tracker_policy

KIND = "matched"
MOTION = "motion.npz"
FILES = ("policy.onnx", MOTION, "humanoid.xml", "arena.xml")


def motion_file(
    clips: Sequence[tuple[str, np.ndarray, np.ndarray]],
    fps: float,
    body_error: Sequence[np.ndarray] | None = None,
) -> dict[str, np.ndarray]:
    """The arrays of motion.npz (module docstring) of ``clips``, each its name, the fighter's
    qpos (T, 35) and the other fighter's at the same frames (T, 35); with the tracker's body
    error of each frame (T,) where the motion is its replay."""
    arrays = {
        "qpos": np.concatenate([np.asarray(q, dtype=np.float64) for _, q, _ in clips]),
        "partner_qpos": np.concatenate([np.asarray(p, dtype=np.float64) for _, _, p in clips]),
        "lengths": np.array([len(q) for _, q, _ in clips]),
        "names": np.array([name for name, _, _ in clips]),
        "fps": np.float64(fps),
    }
    if body_error is not None:
        arrays["body_error_m"] = np.concatenate(
            [np.asarray(e, dtype=np.float64) for e in body_error]
        )
    return arrays


def motion_of(
    arrays: Mapping[str, np.ndarray],
    bones: BoneLengths,
    partner_bones: BoneLengths,
    config: MatchConfig,
) -> MotionDatabase:
    """The MotionDatabase of motion.npz's ``arrays`` (`motion_file`), the fighter on ``bones``
    and its partner on ``partner_bones``; ValueError saying what is wrong."""
    qpos, partner = np.asarray(arrays["qpos"]), np.asarray(arrays["partner_qpos"])
    lengths, names = np.asarray(arrays["lengths"]), np.asarray(arrays["names"])
    fps = float(arrays["fps"])
    if qpos.ndim != 2 or qpos.shape[1] != NQ or partner.shape != qpos.shape:
        raise ValueError(
            f"qpos and partner_qpos must both be (F, {NQ}), got {qpos.shape} and {partner.shape}"
        )
    if (
        lengths.ndim != 1
        or len(names) != len(lengths)
        or lengths.sum() != len(qpos)
        or (lengths < 2).any()
    ):
        raise ValueError(
            f"lengths {lengths.tolist()} do not cut {len(qpos)} frames into clips of 2 or more"
        )
    cuts = np.cumsum(lengths)[:-1]
    own = [
        reference_clip(str(n), q, bones, fps=fps)
        for n, q in zip(names, np.split(qpos, cuts), strict=True)
    ]
    others = [
        reference_clip(f"{n}:partner", q, partner_bones, fps=fps)
        for n, q in zip(names, np.split(partner, cuts), strict=True)
    ]
    return motion_database(own, others, fps=fps, config=config)


def load_motion(
    path: Path,
    bones: BoneLengths,
    partner_bones: BoneLengths,
    *,
    policy_hz: float,
    config: MatchConfig,
) -> MotionDatabase:
    """motion.npz as a MotionDatabase (`motion_of`); BadInput naming the file otherwise."""
    names = ("qpos", "partner_qpos", "lengths", "names", "fps")
    try:
        with np.load(path, allow_pickle=False) as stored:
            arrays = {name: stored[name] for name in names}
    except (OSError, ValueError, KeyError) as error:
        raise BadInput(str(path), f"not a motion file with {', '.join(names)} ({error})") from error
    if float(arrays["fps"]) != policy_hz:
        raise BadInput(
            str(path),
            f"motion at {float(arrays['fps']):g} fps; the policy steps at {policy_hz:g} Hz, a "
            "frame a step",
        )
    try:
        return motion_of(arrays, bones, partner_bones, config)
    except ValueError as error:
        raise BadInput(str(path), str(error)) from error


def load(
    folder: Path, manifest: dict, bones: tuple[BoneLengths, BoneLengths], agent: int
) -> MatchedTracker:
    """The controller of a "matched" folder (files checked by the caller)."""
    policy, policy_hz = tracker_policy(folder, manifest)
    try:
        config = MatchConfig.from_dict(manifest["matcher"])
    except (KeyError, TypeError, ValueError) as error:
        raise BadInput(
            str(folder / "manifest.json"), f"matcher settings unreadable ({error})"
        ) from error
    database = load_motion(
        folder / MOTION, bones[agent], bones[1 - agent], policy_hz=policy_hz, config=config
    )
    return MatchedTracker(policy.run, database)
