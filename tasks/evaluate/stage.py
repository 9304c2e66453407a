"""The evaluate stage: judge a trained pair of policies and hand over the adversary.

Given a finished training run (`load_inputs` reads it, its dataset's start frames and the
adversary's real statistics), `evaluate` computes, with fixed seeds so that a rerun gives the
same tables:

1. Bouts (`tasks.evaluate.bouts.simulate`): `evaluate.episodes` episodes of
   `evaluate.episode_frames` steps of the trained pair (agent 0 the adversary's policy, agent 1
   its partner's), and as many of the untrained pair (the run's networks as its seed
   initialised them, before any training).
2. Damage (MAAIP Table 1): mean damage received and dealt per episode by each agent, for this
   run and for every other finished run on the dataset that minimises or maximises damage,
   each labelled by its `train.reward.control_task` ('none' is imitation only).
3. Heading (MAAIP Table 2): the normalised heading return of every heading run on the dataset
   (this one included, if it is one), with or without the single motion prior; when there is
   none, a note says so and the table stays empty.
4. Style and boxing metrics (`tasks.evaluate.metrics`) of four simulated fighters: the
   trained adversary ('adversary'), the untrained policy's agent 0 ('untrained'), the
   trained partner ('opponent') and agent 0 holding its guard pose, standing still
   ('still', `StillGuard`: the number a policy that only stays up would score), each
   against the adversary's real statistics.
5. The held-out two-sample classifier test (`tasks.evaluate.two_sample`), the headline "moves
   like the footage" figure: the AUC, with its bootstrap interval, of a fresh classifier telling
   1-second windows of the adversary's held-out footage (the dataset's validation interaction
   clips, `footage_clips`) from the trained adversary's, the untrained policy's and the still
   guard's bout windows, from the matched opponent's ('matched': the dataset's tracker playing
   each fighter's own train footage as the motion matcher picks it, both fighters matched), and
   from the dataset's tracker run (`evaluate.tracker`, else its newest) replaying the held-out
   clips ('replay', `dataset_tracker`: the best a physics body has done), with the share of the
   gap between the still guard and the replay that the adversary closes. Each fighter is tested
   again against that replay, both references beside their own train split (the level a perfect
   answer reaches), and beside each AUC stands the feature gap, a graded figure. Where a test
   cannot be made (no held-out footage, too few windows, no tracker run) its row holds NULL and
   the reason.
6. The adversary's opponent folder (`export_opponent`: ONNX policy, MJCF, manifest) with
   onnxruntime's parity against torch on observations recorded in the bouts, and the first
   `evaluate.video_seconds` of the trained episodes, played one after another, rendered to MP4
   (`tasks.media.render_bout`), and the trained episodes' motion (`BOUTS`, which
   `ringside export-motion --run` writes as BVH); all files go to the artifact store.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import torch

from models.arena.controller import Controller
from models.arena.mjcf import arena_mjcf
from models.arena.starts import ReferenceMotions
from models.humanoid.kinematics import NUM_ACTUATED
from models.maaip.networks import Policy, make_networks
from models.tracking.matched import MatchedTracker
from models.tracking.matching import MatchConfig
from storage.artifacts import artifact_name
from storage.db import connect
from storage.files import scratch_dir
from storage.records import output_metrics
from tasks.config import build
from tasks.dataset.config import DatasetConfig, PunchConfig
from tasks.dataset.demonstrations import load_demonstrations
from tasks.dataset.statistics import FighterStatistics
from tasks.dataset.store import FootageClip, dataset_info, footage_clips
from tasks.errors import BadInput
from tasks.evaluate.bouts import Bouts, HeadingTask, simulate
from tasks.evaluate.config import EvaluateConfig
from tasks.evaluate.metrics import (
    boxing_metrics,
    footage_bouts,
    label_fighter,
    rate_interval,
    style_rows,
    style_score,
    window_rates,
)
from tasks.evaluate.motion_files import BOUTS, bouts_npz
from tasks.evaluate.store import (
    DAMAGE_TASKS,
    STAGE,
    ArtifactRow,
    BoxingRow,
    ClassifierRow,
    DamageRow,
    HeadingRow,
    StyleDistanceRow,
    real_statistics,
    resolve_run,
)
from tasks.evaluate.two_sample import (
    FOLDS,
    WINDOW_FEATURES,
    WINDOW_S,
    bout_windows,
    classifier_test,
    feature_gap,
    footage_windows,
    gap_closed,
    replay_windows,
    telltales,
)
from tasks.media import render_bout
from tasks.opponent.export import (
    MatchedFootage,
    TrainedPolicy,
    footage_replay,
    load_trained,
    matched_footage,
    onnx_max_abs_diff,
)
from tasks.opponent.folder import KINDS, MANIFEST, load_opponent
from tasks.opponent.maaip import KIND, OnnxPolicy, TorchPolicy
from tasks.opponent.matched import motion_file, motion_of
from tasks.opponent.still import StillGuard
from tasks.runner import StageOutput
from tasks.train.config import TrainConfig
from tasks.train.store import tracker_run

__all__ = ["STAGE", "EvaluateInputs", "evaluate", "load_inputs"]

# The simulated fighters compared with the adversary: (bouts, agent). 'matched' is the
# dataset's tracker as the matched opponent (both fighters matched, each from its own fighter's
# train footage), where there is a tracker that finished some of it.
POLICIES = {
    "adversary": ("trained", 0),
    "untrained": ("untrained", 0),
    "opponent": ("trained", 1),
    "still": ("still", 0),
    "matched": ("matched", 0),
    "matched_partner": ("matched", 1),
}
# The simulated fighters the two-sample test compares with the adversary's held-out footage,
# besides the tracker replaying it ('replay').
TWO_SAMPLE_POLICIES = ("adversary", "untrained", "still", "matched")
NO_TRACKER = (
    "no finished tracker run on the dataset to replay its held-out clips "
    "(`ringside train --dataset KEY --train-objective track` makes one)"
)
NO_HELD_OUT = (
    "no held-out footage: the dataset's validation split (the last "
    "dataset.validation_fraction of each video) holds no interaction clip of at least "
    "dataset.min_clip_s"
)
NO_TRAIN = "no train footage: the dataset's train split holds no interaction clip"


@dataclass(frozen=True, eq=False)
class EvaluateInputs:
    """Everything the evaluation reads.

    Attributes:
        run: the evaluated run's policy, settings and bones.
        reference: the dataset's interaction frames, to start episodes from.
        real: the adversary's statistics over the dataset's footage.
        punch: the dataset's punch labelling settings.
        compared: other finished runs on the dataset (damage_min/max, heading).
        heldout: the adversary's held-out footage (`footage_clips`).
        tracker: the dataset's newest tracker run (`dataset_tracker`), which replays it.
        train_footage: the adversary's train footage: the level the held-out footage and its
            replay are told apart from their train split at.
        matched: what each fighter of the matched pair plays (`matched_footage`: the train
            clips of its fighter the tracker finished), or why there is no matched pair.
    """

    run: TrainedPolicy
    reference: ReferenceMotions
    real: FighterStatistics
    punch: PunchConfig
    compared: tuple[TrainedPolicy, ...] = ()
    heldout: tuple[FootageClip, ...] = ()
    tracker: TrainedPolicy | None = None
    train_footage: tuple[FootageClip, ...] = ()
    matched: tuple[MatchedFootage, MatchedFootage] | str = NO_TRACKER


def load_inputs(
    db: Path,
    artifacts: Path,
    run_key: str,
    compared: tuple[str, ...] = (),
    tracker_key: str | None = None,
) -> EvaluateInputs:
    """Read run ``run_key``, the runs ``compared`` with it, its dataset and tracker run
    ``tracker_key`` (`dataset_tracker`), if any."""
    with connect(db, read_only=True) as con:
        info = resolve_run(con, run_key)
        others = [resolve_run(con, key) for key in compared]
        tracker = None if tracker_key is None else tracker_run(con, tracker_key)
        metrics = {
            i.run_key: output_metrics(con, "train", i.dataset_key, i.run_key)
            for i in (info, *others, *([tracker] if tracker else []))
        }
        demos = load_demonstrations(con, info.dataset_key)
        real = real_statistics(con, info.dataset_key)
        heldout = tuple(footage_clips(con, info.dataset_key, split="validation"))
        train_footage = tuple(footage_clips(con, info.dataset_key, split="train"))
        dataset = build(
            DatasetConfig, dataset_info(con, info.dataset_key).config, section="dataset"
        )
    replayer = (
        None if tracker is None else load_trained(artifacts, tracker, metrics[tracker.run_key])
    )
    evaluated = load_trained(artifacts, info, metrics[info.run_key])
    played: tuple[MatchedFootage, MatchedFootage] | str = NO_TRACKER
    if replayer is not None and replayer.bones != evaluated.bones:
        played = "no matched opponent: the tracker's humanoids are not the evaluated run's"
    elif replayer is not None:
        try:
            played = (matched_footage(db, replayer, 0), matched_footage(db, replayer, 1))
        except BadInput as error:
            played = f"no matched opponent: {error}"
    return EvaluateInputs(
        run=evaluated,
        reference=demos.reference,
        real=real,
        punch=dataset.punch,
        compared=tuple(load_trained(artifacts, i, metrics[i.run_key]) for i in others),
        heldout=heldout,
        train_footage=train_footage,
        tracker=replayer,
        matched=played,
    )


def untrained_policy(config: TrainConfig, reference: ReferenceMotions) -> Policy:
    """The run's policy before training: its networks as the run's seed initialised them from
    the dataset's ``reference`` (`Trainer` seeds one generator with `train.seed` and makes the
    networks from it and the reference's stance)."""
    networks = make_networks(
        config, generator=torch.Generator().manual_seed(config.seed), stance=reference.stance
    )
    return networks.policy.eval()


def heading_task(config: TrainConfig) -> HeadingTask | None:
    reward = config.reward
    if reward.control_task != "heading":
        return None
    return HeadingTask(target_speed=reward.heading_speed, scale=reward.heading_scale)


def _agents(policy: Policy) -> tuple[Controller, Controller]:
    """Both agents of ``policy``, acting with their mean actions."""
    return TorchPolicy(policy, 0), TorchPolicy(policy, 1)


def _still_pair(reference: ReferenceMotions) -> tuple[Controller, Controller]:
    """Both fighters holding their stance, standing still (`StillGuard`)."""
    if reference.stance is None:
        return StillGuard(np.zeros(NUM_ACTUATED)), StillGuard(np.zeros(NUM_ACTUATED))
    return StillGuard(reference.stance[0]), StillGuard(reference.stance[1])


def _bouts(
    controllers: tuple[Controller, Controller],
    run: TrainedPolicy,
    reference: ReferenceMotions,
    *,
    episodes: int,
    frames: int,
    seed: int,
) -> Bouts:
    return simulate(
        controllers,
        reference=reference,
        bones=run.bones,
        env_config=run.config.env,
        episodes=episodes,
        frames=frames,
        seed=seed,
        heading=heading_task(run.config),
    )


def _damage_rows(run: TrainedPolicy, bouts: Bouts, frames: int) -> list[DamageRow]:
    return [
        DamageRow(
            run.run_key,
            run.config.reward.control_task,
            agent,
            float(bouts.damage[:, agent].mean()),
            float(bouts.damage[:, 1 - agent].mean()),
            bouts.episodes,
            frames,
        )
        for agent in (0, 1)
    ]


def _export(run: TrainedPolicy, bouts: Bouts, folder: Path) -> tuple[float, dict[str, bytes]]:
    """Export the adversary, check onnxruntime against torch on the bouts' observations of
    agent 0; (max abs difference, {name in the opponent folder: bytes})."""
    out = run.export(0, folder)
    exported = load_opponent(out).controller
    assert isinstance(exported, OnnxPolicy)  # a MAAIP run exports MAAIP's kind
    tasks = None if bouts.tasks is None else bouts.tasks[:, 0]
    diff = onnx_max_abs_diff(run.policy, 0, exported, bouts.observations[:, 0], tasks)
    files = (*KINDS[KIND].files, MANIFEST)
    return diff, {f"opponent/{name}": (out / name).read_bytes() for name in files}


def _video(
    model: mujoco.MjModel, bouts: Bouts, seconds: float, folder: Path
) -> tuple[bytes, int] | None:
    """The bouts' episodes in arena ``model`` one after another, their first ``seconds``, as
    an MP4: its bytes and frames."""
    count = round(seconds * bouts.policy_hz)
    if count < 1:
        return None
    played = np.concatenate([bouts.episode_qpos(e) for e in range(bouts.episodes)])[:count]
    path = folder / "bout.mp4"
    written = render_bout(model, played, path, fps=bouts.policy_hz)
    return path.read_bytes(), written


def _windows(count: int) -> str:
    return f"{count} window" + ("" if count == 1 else "s")


def tracker_replay(
    tracker: TrainedPolicy, clips: tuple[FootageClip, ...], split: str
) -> np.ndarray:
    """(W, D) windows of the adversary in ``tracker``'s replay of footage ``clips`` (of the
    dataset's ``split``): agent 0 tracking the adversary's clip, agent 1 the opponent's, both
    where the footage has them, from each clip's first frame (`footage_replay`)."""
    replay = footage_replay(tracker, clips, split)
    if replay is None:
        return np.zeros((0, len(WINDOW_FEATURES)))
    return replay_windows(replay, float(tracker.config.env.policy_hz))


Windows = np.ndarray | str  # (W, D) window vectors, or why there are none

# How each side's windows are named where there are too few of them.
_MADE = {
    ("footage", "real"): "the held-out footage gives",
    ("footage", "train"): "the train footage gives",
    ("replay", "real"): "the replay gives",
    ("replay", "train"): "the replay of the train clips gives",
    "replay": "the replay gives",
    "bouts": "the bouts give",
}


def _why_not(windows: Windows, made: str) -> str | None:
    """Why ``windows`` cannot take part in a test, or None when they can."""
    if isinstance(windows, str):
        return windows
    if len(windows) < FOLDS:
        return f"{made} {_windows(len(windows))} of {WINDOW_S:g} s; the test needs {FOLDS}"
    return None


def classifier_row(
    reference: str, real: Windows, policy: str, windows: Windows, *, seed: int
) -> ClassifierRow:
    """One fighter's ``windows`` tested against the ``real`` windows of ``reference``
    ('footage' or 'replay'), or NULL and why not."""
    counts = tuple(0 if isinstance(w, str) else len(w) for w in (real, windows))
    made = _MADE[(reference, "train")] if policy == "train" else _MADE.get(policy, _MADE["bouts"])
    reason = _why_not(real, _MADE[(reference, "real")]) or _why_not(windows, made)
    if reason is not None:
        return ClassifierRow(policy, None, None, None, *counts, reason, reference=reference)
    assert not isinstance(real, str) and not isinstance(windows, str)
    result = classifier_test(real, windows, seed=seed)
    return ClassifierRow(
        policy,
        result.auc,
        result.low,
        result.high,
        *counts,
        None,
        telltales(real, windows),
        reference=reference,
        feature_gap=feature_gap(real, windows),
    )


# Each reference's metric names: its AUCs and feature gaps, suffixed by the policy.
_METRIC = {
    "footage": ("two_sample_auc", "feature_gap"),
    "replay": ("two_sample_auc_vs_replay", "feature_gap_vs_replay"),
}


def two_sample_rows(
    references: dict[str, Windows],
    levels: dict[str, Windows],
    simulated: dict[str, Windows],
    *,
    seed: int,
) -> tuple[list[ClassifierRow], dict[str, float]]:
    """The two-sample test's rows and metrics.

    Args:
        references: the held-out windows each fighter is judged against, or why there are
            none: 'footage' (the adversary's held-out footage) and 'replay' (the tracker's
            replay of the held-out clips).
        levels: the same of the train split ('footage': the train footage; 'replay': the
            tracker's replay of the train clips), tested as policy 'train': the level a
            perfect answer would reach.
        simulated: each simulated fighter's bout windows (`TWO_SAMPLE_POLICIES`), or why none.

    Against the footage, the replay is tested too. The metrics: each measured row's AUC and
    feature gap (`_METRIC`, the policy a suffix, none for the adversary; the adversary's interval
    too), and the share of the still-to-replay gap the adversary (and, suffixed, the matched
    opponent) closes against the footage, on the AUC (``two_sample_gap_closed``) and on the
    feature gap (``feature_gap_closed``).
    """
    rows, metrics = [], {}
    for reference, (auc_name, gap_name) in _METRIC.items():
        fighters = dict(simulated)
        if reference == "footage":
            fighters["replay"] = references["replay"]
        fighters["train"] = levels[reference]
        for policy, windows in fighters.items():
            row = classifier_row(reference, references[reference], policy, windows, seed=seed)
            rows.append(row)
            if row.auc is None:
                continue
            suffix = "" if policy == "adversary" else f"_{policy}"
            metrics[f"{auc_name}{suffix}"] = row.auc
            metrics[f"{gap_name}{suffix}"] = row.feature_gap
            if policy == "adversary":
                metrics[f"{auc_name}_low"] = row.auc_low
                metrics[f"{auc_name}_high"] = row.auc_high
    for name, figure in (
        ("two_sample_gap_closed", "two_sample_auc"),
        ("feature_gap_closed", "feature_gap"),
    ):
        for suffix in ("", "_matched"):
            closed = gap_closed(
                metrics.get(f"{figure}{suffix}"),
                metrics.get(f"{figure}_still"),
                metrics.get(f"{figure}_replay"),
            )
            if closed is not None:
                metrics[f"{name}{suffix}"] = closed
    return rows, metrics


def held_out_overlap(
    played: tuple[MatchedFootage, ...], heldout: tuple[FootageClip, ...]
) -> list[str]:
    """The clips of ``played`` that share a step of footage with a ``heldout`` clip (by video and
    steps; `FootageClip.name` is "video@start"): none, or the held-out windows are not held
    out."""
    spans = [(c.video_id[:12], c.start_step, c.start_step + len(c.qpos)) for c in heldout]
    found = []
    for footage in played:
        for name, qpos, _ in footage.clips:
            video, _, start = name.rpartition("@")
            first, end = int(start), int(start) + len(qpos)
            if any(v == video and first < e and s < end for v, s, e in spans):
                found.append(name)
    return found


def _acting(policy: Policy, agent: int) -> Callable[[np.ndarray], np.ndarray]:
    """Agent ``agent``'s mean action of ``policy`` as a function of observations, taken as
    float32 as in training."""

    def act(observation: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            given = torch.from_numpy(np.asarray(observation, dtype=np.float32))
            return policy(given, agent, None).double().numpy()

    return act


def matched_pair(
    tracker: TrainedPolicy, played: tuple[MatchedFootage, MatchedFootage]
) -> tuple[MatchedTracker, MatchedTracker]:
    """Both fighters as matched opponents (`tasks.opponent.matched`, the matcher's default
    settings, as `ringside export --matched` writes them): ``tracker``'s policy playing each
    fighter's own footage of ``played``."""
    hz = float(tracker.config.env.policy_hz)
    pair = []
    for agent, footage in enumerate(played):
        database = motion_of(
            motion_file(footage.clips, hz),
            tracker.bones[agent],
            tracker.bones[1 - agent],
            MatchConfig(),
        )
        pair.append(MatchedTracker(_acting(tracker.policy, agent), database))
    return pair[0], pair[1]


def held_out_rates(
    heldout: tuple[FootageClip, ...],
    punch: PunchConfig,
    fps: int,
    *,
    timestep: float,
    seed: int,
) -> dict[str, float]:
    """The held-out footage's punches and steps per minute, labelled as a simulated fighter's
    are (`label_fighter` on the footage, each clip laid in an arena of its fighter's own bones,
    as `footage_windows` compiles them: another body's legs would lift its feet off the floor
    or sink them), each the mean over its 1-s windows with that mean's bootstrap interval
    (``_low``, ``_high``): what a fighter's rates are compared with. Empty without held-out
    footage a window long."""
    per_window: dict[str, list[np.ndarray]] = {}
    for bones in dict.fromkeys(c.bones for c in heldout):
        model = mujoco.MjModel.from_xml_string(arena_mjcf((bones, bones), timestep=timestep))
        clips = [(c.qpos, c.other_qpos) for c in heldout if c.bones == bones]
        footage = footage_bouts(model, clips, fps)
        labelled = label_fighter(footage, 0, model=model, bones=bones, punch=punch)
        for name, rates in window_rates(labelled, footage, WINDOW_S).items():
            per_window.setdefault(name, []).append(rates)
    out = {}
    for name, parts in per_window.items():
        rates = np.concatenate(parts)
        if len(rates):
            out[name], out[f"{name}_low"], out[f"{name}_high"] = rate_interval(rates, seed)
    return out


def evaluate(inputs: EvaluateInputs, config: EvaluateConfig) -> StageOutput:
    """The evaluate stage's rows, metrics and files (the exported opponent, the video, the
    bouts' motion) for run ``inputs.run`` (module docstring)."""
    run = inputs.run
    size = {"episodes": config.episodes, "frames": config.episode_frames, "seed": config.seed}
    bouts = {
        "trained": _bouts(_agents(run.policy), run, inputs.reference, **size),
        "untrained": _bouts(
            _agents(untrained_policy(run.config, inputs.reference)), run, inputs.reference, **size
        ),
        "still": _bouts(_still_pair(inputs.reference), run, inputs.reference, **size),
    }
    if not isinstance(inputs.matched, str):
        overlap = held_out_overlap(inputs.matched, inputs.heldout)
        if overlap:
            raise ValueError(f"the matched opponent would play held-out footage: {overlap}")
        tracker = inputs.tracker
        assert tracker is not None
        bouts["matched"] = simulate(
            matched_pair(tracker, inputs.matched),
            reference=inputs.reference,
            bones=tracker.bones,
            env_config=tracker.config.env,
            episodes=config.episodes,
            frames=config.episode_frames,
            seed=config.seed,
        )
    model = mujoco.MjModel.from_xml_string(arena_mjcf(run.bones, timestep=run.config.env.timestep))
    hz = bouts["trained"].policy_hz
    style, boxing, scores, fighters = [], [], {}, {}
    for policy, (which, agent) in POLICIES.items():
        if which not in bouts:
            continue
        fighter = label_fighter(
            bouts[which], agent, model=model, bones=run.bones[agent], punch=inputs.punch
        )
        fighters[policy] = fighter
        rows = style_rows(fighter.statistics, inputs.real)
        scores[policy] = style_score(rows)
        style += [
            StyleDistanceRow(policy, r.statistic, r.kind, r.simulated, r.real, r.distance)
            for r in rows
        ]
        measured = boxing_metrics(
            fighter,
            bouts[which],
            opponent_bones=run.bones[1 - agent],
            radius_m=config.punch_target_radius_m,
        )
        boxing += [BoxingRow(policy, name, value) for name, value in measured.items()]
        if policy == "adversary":
            adversary_boxing = measured
    footage_rates = held_out_rates(
        inputs.heldout, inputs.punch, hz, timestep=run.config.env.timestep, seed=config.seed
    )
    boxing += [BoxingRow("footage", name, value) for name, value in footage_rates.items()]

    simulated: dict[str, Windows] = {
        p: bout_windows(model, bouts[POLICIES[p][0]], POLICIES[p][1])
        if POLICIES[p][0] in bouts
        else str(inputs.matched)
        for p in TWO_SAMPLE_POLICIES
    }
    held_out, train = (
        footage_windows([(c.qpos, c.other_qpos, c.bones) for c in clips], hz) if clips else why
        for clips, why in ((inputs.heldout, NO_HELD_OUT), (inputs.train_footage, NO_TRAIN))
    )
    tracker = inputs.tracker
    references = {
        "footage": held_out,
        "replay": NO_TRACKER
        if tracker is None
        else tracker_replay(tracker, inputs.heldout, "held-out"),
    }
    levels = {
        "footage": train,
        "replay": NO_TRACKER
        if tracker is None
        else tracker_replay(tracker, inputs.train_footage, "train"),
    }
    two_sample, two_sample_metrics = two_sample_rows(
        references, levels, simulated, seed=config.seed
    )
    notes = []
    if isinstance(inputs.matched, str) and tracker is not None:
        notes.append(f"matched opponent: not evaluated, {inputs.matched}")
    if "two_sample_auc" not in two_sample_metrics:
        notes.append(f"two-sample test: not measured, {two_sample[0].reason}")
    damage = _damage_rows(run, bouts["trained"], config.episode_frames)
    damage_runs = [c for c in inputs.compared if c.config.reward.control_task in DAMAGE_TASKS]
    for other in damage_runs:
        damage += _damage_rows(
            other,
            _bouts(_agents(other.policy), other, inputs.reference, **size),
            config.episode_frames,
        )
    if not damage_runs:
        notes.append(
            f"damage table: only this run ({run.config.reward.control_task}); no finished "
            f"damage_min or damage_max run on dataset {run.dataset_key[:12]} to compare"
        )
    heading_runs = [r for r in (run, *inputs.compared) if heading_task(r.config) is not None]
    heading = []
    for other in heading_runs:
        played = _bouts(
            _agents(other.policy),
            other,
            inputs.reference,
            episodes=config.heading_episodes,
            frames=config.heading_frames,
            seed=config.seed,
        )
        for agent in (0, 1):
            # Normalised by the episode's full length: a fall forfeits the rest (reward 0).
            value = float((played.task_return[:, agent] / config.heading_frames).mean())
            heading.append(
                HeadingRow(
                    other.run_key,
                    other.config.reward.w_motion > 0,
                    agent,
                    value,
                    config.heading_episodes,
                    config.heading_frames,
                )
            )
    if not heading_runs:
        notes.append(
            f"heading table: not available, no finished heading run on dataset "
            f"{run.dataset_key[:12]} (MAAIP Table 2 compares heading runs with and without the "
            "single motion prior)"
        )

    trained = bouts["trained"]
    with scratch_dir("evaluate") as tmp:
        diff, files = _export(run, trained, Path(tmp) / "opponent")
        video = _video(model, trained, config.video_seconds, Path(tmp))
    if video is not None:
        files["bout.mp4"] = video[0]
    files[BOUTS] = bouts_npz(trained.qpos, trained.frames, run.bones)
    # Each file under the name the evaluation gives it, stored by its bytes' name.
    stored = {name: artifact_name(data, Path(name).suffix) for name, data in files.items()}
    media = [ArtifactRow(name, artifact) for name, artifact in stored.items()]

    unstable = int(trained.unstable.sum())
    if unstable:
        notes.append(f"{unstable} of {trained.episodes} trained episodes blew up (unstable)")
    metrics = {
        "onnx_max_abs_diff": diff,
        "style_score": scores["adversary"],
        "style_score_untrained": scores["untrained"],
        "style_score_opponent": scores["opponent"],
        "style_score_still": scores["still"],
        # As training counts them: episodes ended by a fall per simulated minute.
        "falls_per_min": trained.falls_per_min,
        "falls_per_min_untrained": bouts["untrained"].falls_per_min,
        "falls_per_min_still": bouts["still"].falls_per_min,
        **(
            {
                "falls_per_min_matched": bouts["matched"].falls_per_min,
                "style_score_matched": scores["matched"],
                "style_score_matched_partner": scores["matched_partner"],
            }
            if "matched" in bouts
            else {}
        ),
        "episode_length_s": float(trained.steps.mean()) / trained.policy_hz,
        "damage_received_n": float(trained.damage[:, 0].mean()),
        "damage_dealt_n": float(trained.damage[:, 1].mean()),
        "unstable_episodes": float(unstable),
        "video_frames": float(video[1]) if video is not None else 0.0,
        **two_sample_metrics,
        **{f"footage_{name}": value for name, value in footage_rates.items()},
    }
    for name in ("punch_accuracy_pct", "foot_skating_cm_per_frame", "time_in_guard_pct"):
        if name in adversary_boxing:
            metrics[name] = adversary_boxing[name]
    for row in heading:
        if row.run_key == run.run_key:
            metrics[f"heading_return_{row.agent}"] = row.normalized_return
    return StageOutput(
        rows={
            "evaluate_damage": damage,
            "evaluate_heading": heading,
            "evaluate_style": style,
            "evaluate_boxing": boxing,
            "evaluate_classifier": two_sample,
            "evaluate_artifacts": media,
        },
        metrics={k: float(v) for k, v in metrics.items() if math.isfinite(v)},
        notes=tuple(notes),
        files={stored[name]: data for name, data in files.items()},
    )
