"""An exported opponent: one folder that other software can load and run without torch.

The folder (`tasks.opponent.export` writes it) holds its kind's files and a manifest:

================  ===============================================================================
manifest.json     ``format`` (2), the controller's ``kind`` (a key of `KINDS`), what the files
                  are (SHA-256 each), the observation and action layouts, the rates (``env``),
                  the bones, each fighter's guard (the 28 hinge angles a bout starts it in, a
                  pose it holds unaided), the agent it is, the dataset and training keys and
                  the run's last metrics
humanoid.xml      the fighter's MuJoCo model, with its measured bones
arena.xml         both fighters facing each other on a floor, as the policy was trained in
================  ===============================================================================

and, by kind:

- "maaip" (`tasks.opponent.maaip`): policy.onnx, MAAIP's policy, (B, 274) in.
- "tracker" (`tasks.opponent.tracker`): policy.onnx, the motion tracker's policy, (B, 451) in,
  and clip.npz, the reference clip it plays.
- "matched" (`tasks.opponent.matched`): the tracker's policy.onnx and motion.npz, the fighter's
  footage with the other fighter's at the same frames, which the partner-aware motion matcher
  picks from (its settings in the manifest).

A folder of format 1 (written before the kinds) names no kind: it is read as "maaip", which it
is. `load_opponent` refuses, in one line naming the file (`BadInput`), a kind it does not know,
a missing file, a digest that does not match, and a policy of another size than its kind's.

This module reads the folder with onnxruntime, MuJoCo and numpy only, so a sparring engine
needs neither torch nor a GPU.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np

from models.arena.controller import Controller
from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import NUM_ACTUATED
from storage.files import sha256_file
from tasks.errors import BadInput
from tasks.opponent import maaip, matched, tracker

FORMAT = 2
READS = (1, 2)  # format 1: before the kinds, always MAAIP's policy
MANIFEST = "manifest.json"


@dataclass(frozen=True)
class Kind:
    """One kind of controller an opponent folder can hold.

    Attributes:
        files: the folder's files besides the manifest, each with its SHA-256 in it.
        load: (folder, manifest, both fighters' bones, agent) -> its controller, the files
            already checked against their digests; BadInput naming a file it cannot use.
    """

    files: tuple[str, ...]
    load: Callable[[Path, dict, tuple[BoneLengths, BoneLengths], int], Controller]


KINDS: Mapping[str, Kind] = MappingProxyType(
    {
        maaip.KIND: Kind(maaip.FILES, maaip.load),
        tracker.KIND: Kind(tracker.FILES, tracker.load),
        matched.KIND: Kind(matched.FILES, matched.load),
    }
)


@dataclass(frozen=True, eq=False)
class Opponent:
    """A loaded opponent folder.

    Attributes:
        folder: where it was loaded from.
        manifest: the parsed manifest.json.
        kind: its controller's kind (a key of `KINDS`).
        controller: what picks its actions (`models.arena.controller`).
        agent: which of the training run's agents it is (0: the adversary), its arena slot.
        bones: both fighters' bones as trained (agent 0's, then agent 1's).
        guard: (2, 28) both fighters' guards, the hinge angles they start a bout in (the rest
            pose, all zeros, for a folder written before guards were exported).
    """

    folder: Path
    manifest: dict
    kind: str
    controller: Controller
    agent: int
    bones: tuple[BoneLengths, BoneLengths]
    guard: np.ndarray

    @property
    def task_dim(self) -> int:
        """Extra policy inputs its controller takes: 2 for a heading policy (MAAIP's only), else
        0."""
        return self.controller.task_dim if isinstance(self.controller, maaip.OnnxPolicy) else 0


def read_manifest(folder: Path) -> dict:
    """The folder's manifest, of a format this Ringside reads; BadInput otherwise."""
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
    if not isinstance(manifest, dict) or manifest.get("format") not in READS:
        got = manifest.get("format") if isinstance(manifest, dict) else None
        raise BadInput(
            str(manifest_path),
            f"format {got!r}; this Ringside reads formats {', '.join(map(str, READS))}",
        )
    return manifest


def folder_kind(folder: Path, manifest: dict) -> str:
    """The kind ``manifest`` names ("maaip" for format 1); BadInput for one not in `KINDS`."""
    kind = maaip.KIND if manifest["format"] == 1 else manifest.get("kind")
    if kind not in KINDS:
        raise BadInput(
            str(Path(folder) / MANIFEST),
            f"kind {kind!r} is not one this Ringside loads ({', '.join(KINDS)})",
        )
    return kind


def check_files(folder: Path, manifest: dict, files: tuple[str, ...]) -> None:
    """Each of ``files`` is in ``folder`` and matches the manifest's SHA-256; BadInput naming
    the first that does not."""
    manifest_path = Path(folder) / MANIFEST
    digests = manifest.get("files", {})
    for name in files:
        path = Path(folder) / name
        if not path.is_file():
            raise BadInput(str(path), "missing from the opponent folder")
        if name not in digests:
            raise BadInput(str(manifest_path), f"lists no SHA-256 for {name}")
        if sha256_file(path) != digests[name]:
            raise BadInput(
                str(path), "does not match the manifest's SHA-256 (changed or from another export)"
            )


def load_opponent(folder: Path, kind: str | None = None) -> Opponent:
    """Load and check an opponent folder, of ``kind`` where one is given; BadInput naming the
    file and the problem otherwise."""
    folder = Path(folder)
    manifest = read_manifest(folder)
    manifest_path = folder / MANIFEST
    found = folder_kind(folder, manifest)
    if kind is not None and found != kind:
        raise BadInput(str(manifest_path), f"an opponent of kind {found!r}, not {kind!r}")
    kind = found
    check_files(folder, manifest, KINDS[kind].files)
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
    pair = (bones[0], bones[1])
    controller = KINDS[kind].load(folder, manifest, pair, agent)
    return Opponent(folder, manifest, kind, controller, agent, pair, guard)
