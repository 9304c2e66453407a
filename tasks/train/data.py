"""Demonstrations made from a DeepMimic sample clip, for training without footage (tests and
benchmarks); a dataset's own are read by `tasks.dataset.demonstrations.load_demonstrations`."""

from __future__ import annotations

from pathlib import Path

import mujoco

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.compiled import velocities
from models.humanoid.motion import RATE
from models.maaip.demonstrations import (
    Demonstrations,
    demonstrations_from_reference,
    facing_reference,
)
from tasks.deepmimic import clip_path, load_deepmimic, retarget


def clip_demonstrations(
    assets: Path,
    clip: str = "punch",
    bones: tuple[BoneLengths, BoneLengths] = (BoneLengths(), BoneLengths()),  # noqa: B008
) -> Demonstrations:
    """A DeepMimic sample clip performed by two fighters facing each other
    (`facing_reference`), as a dataset would hold it. Key "clip:<clip>"."""
    qpos = retarget(load_deepmimic(clip_path(assets, clip)))
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(bones[0]))
    reference = facing_reference(qpos, velocities(model, qpos, RATE))
    return demonstrations_from_reference(reference, bones, key=f"clip:{clip}")
