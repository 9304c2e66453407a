"""The train stage's tracker (train.objective 'track', `models.tracking`): a dataset's
footage as the clips to track, and what the trained tracker makes of each clip.

Agent 0 tracks the adversary's footage, agent 1 the opponent's at the same steps
(`paired_tracking`): every unbroken run of an interaction clip's steps lifted for both fighters
(`footage_clips`), on the two humanoids the dataset trains (`training_bones`). Training reads
the train split only; once trained, every clip of both splits is tracked from its first frame
(`clip_tracking`), so the held-out clips' errors judge the tracker on footage it never learned
from, and each clip's errors say how well a physics body can follow it (a clip the lift made
impossible scores badly).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import duckdb
import numpy as np

from models.humanoid.boxer import BoneLengths
from models.maaip.networks import Policy
from models.tracking.clips import TrackingData, reference_clip, tracking_data
from models.tracking.gate import GateRow, gate_of, play_clips
from models.tracking.matched import matched_streams
from models.tracking.matching import motion_database
from tasks.dataset.store import FootageClip, dataset_info, footage_clips, training_bones
from tasks.errors import BadInput
from tasks.roles import ROLES
from tasks.train.config import TrainConfig

SPLITS = ("train", "validation")


@dataclass(frozen=True)
class TrackingRow(GateRow):
    """A ``train_tracking`` row: one clip of split ``split`` tracked by one agent (`GateRow`)."""

    split: str


def paired_tracking(
    clips: Sequence[FootageClip], bones: tuple[BoneLengths, BoneLengths], *, fps: float, key: str
) -> TrackingData | None:
    """Footage ``clips`` as TrackingData, paired clip by clip: agent 0 follows each clip's
    fighter, agent 1 the other fighter at the same steps (so `Tracker.reset(as_filmed=True)` may
    start them together); None when no clip has the two frames tracking needs (a first and a
    next)."""
    runs = [c for c in clips if len(c.qpos) >= 2]
    if not runs:
        return None
    qpos = ({c.name: c.qpos for c in runs}, {c.name: c.other_qpos for c in runs})
    return tracking_data(qpos, bones, fps=fps, key=key)


def with_streams(data: TrackingData, config: TrainConfig) -> TrackingData:
    """``data`` with `TrackConfig.matched_streams` matched streams of both fighters added
    (`matched_streams`, on the default matcher, seeded by the run's seed), named "stream:k".

    Raises:
        BadInput: streams are asked for but no clip is long enough to match from.
    """
    count = config.track.matched_streams
    if count == 0:
        return data
    try:
        databases = tuple(
            motion_database(data.clips[a], data.clips[1 - a], fps=data.fps) for a in range(2)
        )
    except ValueError as error:
        raise BadInput(f"dataset {data.key}", f"train.track.matched_streams: {error}") from error
    frames = max(2, round(config.track.matched_stream_s * data.fps))
    streams = matched_streams(
        databases, count=count, frames=frames, rng=np.random.default_rng([config.seed, 2])
    )
    clips = tuple(
        data.clips[a]
        + tuple(
            reference_clip(f"stream:{k}", q, data.bones[a], fps=data.fps)
            for k, q in enumerate(streams[a])
        )
        for a in range(2)
    )
    return dataclasses.replace(data, key=f"{data.key}+{count}streams", clips=clips)


def footage_tracking(
    con: duckdb.DuckDBPyConnection,
    dataset_key: str,
    *,
    fps: float,
    splits: Sequence[str] = SPLITS,
) -> dict[str, TrackingData]:
    """The footage of dataset ``dataset_key``'s ``splits`` as TrackingData (module docstring),
    by split; a split without footage is left out.

    Raises:
        BadInput: the train split holds no interaction clip to track.
    """
    info = dataset_info(con, dataset_key)
    bones = training_bones(con, info.dataset_key)
    found = {}
    for split in splits if bones is not None else ():
        clips = footage_clips(con, info.dataset_key, ROLES[0], split)
        made = paired_tracking(clips, bones, fps=fps, key=f"{info.dataset_key}:{split}")
        if made is not None:
            found[split] = made
    if "train" not in found:
        raise BadInput(
            f"dataset {info.dataset_key}",
            "its train split holds no interaction clip lifted for both fighters: nothing to track",
        )
    return found


def clip_tracking(
    policy: Policy, data: dict[str, TrackingData], config: TrainConfig
) -> tuple[list[TrackingRow], dict[str, float]]:
    """Every clip of every split of ``data`` tracked from its first frame on ``policy``'s mean
    (`play_clips`): the rows, and the metrics: each split's share of clips finished (%) and mean
    body and root errors (cm), the validation split's named '..._held_out'."""
    rows, metrics = [], {}
    for split, clips in data.items():
        played = play_clips(policy, clips, config)
        rows += [TrackingRow(**dataclasses.asdict(r), split=split) for r in played.rows]
        gate = gate_of(played.rows)
        suffix = "" if split == "train" else "_held_out"
        metrics[f"track_finished_pct{suffix}"] = gate.finished_pct
        metrics[f"track_body_error_cm{suffix}"] = gate.body_error_cm
        metrics[f"track_root_error_cm{suffix}"] = gate.root_error_cm
    return rows, metrics
