"""Export a trained fighter as an opponent folder of its kind (`tasks.opponent.folder` says what
is in it): MAAIP's policy (`export_opponent`), the motion tracker's with the clip it plays
(`export_tracker`), or with the footage the motion matcher picks from (`export_matched`).

The policy goes to ONNX with torch's TorchScript-based exporter (`dynamo=False`: the newer
exporter needs the onnxscript package, which nothing else here uses), as the normaliser and
the Gaussian's mean of one agent, the batch dimension dynamic. The folder is written beside
its final place and renamed into it, so a killed export leaves no half folder.
"""

from __future__ import annotations

import hashlib
import io
import json
import shutil
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from models.arena.config import EnvConfig
from models.arena.mjcf import DEFAULT_PREFIXES, arena_mjcf
from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.compiled import humanoid_index
from models.humanoid.kinematics import HINGE_NAMES, JOINT_LAYOUT, NQ, action_to_joint_targets
from models.humanoid.observations import OBSERVATION_DIM, OPPONENT_BLOCKS, SELF_BLOCKS
from models.humanoid.stance import guard_pose
from models.maaip.networks import Policy
from models.maaip.trainer import checkpoint_policy
from models.tracking.gate import Played, play_clips
from models.tracking.matching import MatchConfig
from models.tracking.task import TRACK_OBSERVATION_DIM
from storage.artifacts import read_bytes
from storage.db import connect
from storage.records import output_metrics
from tasks.config import build
from tasks.dataset.store import FootageClip, footage_clips
from tasks.deepmimic import CLIPS, WALKER_CLIPS, clip_path, load_deepmimic, retarget
from tasks.errors import BadInput
from tasks.evaluate.bouts import mujoco_stepping
from tasks.opponent import maaip, matched, tracker
from tasks.opponent.folder import FORMAT, KINDS, MANIFEST
from tasks.opponent.maaip import OnnxPolicy
from tasks.roles import ROLES
from tasks.train.config import TrainConfig
from tasks.train.store import RunInfo, clips_finished, finished_run
from tasks.train.tracker import paired_tracking

ONNX_OPSET = 17


@dataclass(frozen=True, eq=False)
class TrainedPolicy:
    """A training run's committed shared policy and what it was trained on."""

    run_key: str
    dataset_key: str
    iteration: int
    config: TrainConfig
    policy: Policy
    bones: tuple[BoneLengths, BoneLengths]
    metrics: dict[str, float]

    @property
    def kind(self) -> str:
        """The kind of opponent folder it exports as."""
        return tracker.KIND if self.config.objective == "track" else maaip.KIND

    def export(
        self,
        agent: int,
        out: Path,
        clip: tuple[str, np.ndarray] | None = None,
        footage: MatchedFootage | None = None,
    ) -> Path:
        """One of its fighters as an opponent folder, the manifest naming the dataset, the run,
        its iteration and metrics: MAAIP's (`export_opponent`), or a tracker's playing
        ``clip`` (its name and qpos (T, 35) on that fighter's bones at the policy's rate,
        `export_tracker`) or the ``footage`` the motion matcher picks from (`export_matched`)."""
        facts = {
            "dataset_key": self.dataset_key,
            "run_key": self.run_key,
            "iteration": self.iteration,
            "metrics": self.metrics,
        }
        if footage is not None:
            if self.kind != tracker.KIND or clip is not None:
                raise ValueError(f"run {self.run_key[:12]}: only a tracker plays footage, alone")
            return export_matched(
                out,
                policy=self.policy,
                agent=agent,
                bones=self.bones,
                env=self.config.env,
                footage=footage,
                matcher=MatchConfig(),
                facts={**facts, "left_out": list(footage.left_out)},
            )
        if self.kind == tracker.KIND:
            if clip is None:
                raise ValueError(f"run {self.run_key[:12]} is a tracker: give the clip it plays")
            return export_tracker(
                out,
                policy=self.policy,
                agent=agent,
                bones=self.bones,
                env=self.config.env,
                clip=clip,
                facts=facts,
            )
        if clip is not None:
            raise ValueError(f"run {self.run_key[:12]} is MAAIP's: it plays no clip")
        return export_opponent(
            out,
            policy=self.policy,
            agent=agent,
            bones=self.bones,
            env=self.config.env,
            facts=facts,
        )


@dataclass(frozen=True)
class MatchedFootage:
    """What a matched opponent plays: clips of its fighter's train footage (name, the
    fighter's qpos (T, 35), the other fighter's at the same frames), the names of those left
    out, where the fighter's motion comes from ("footage" as filmed, or the tracker's "replay"
    of it, `replayed_footage`) and, for the replay, each clip's body error frame by frame (T,)
    in metres."""

    clips: tuple[tuple[str, np.ndarray, np.ndarray], ...]
    left_out: tuple[str, ...]
    source: str = "footage"
    body_error: tuple[np.ndarray, ...] | None = None


# The last steps of a replay that fell or drifted are the body going down, not the footage
# played: such a replay is kept up to this long before it ended.
_FALLING_S = 0.5


def matched_footage(db: Path, trained: TrainedPolicy, agent: int) -> MatchedFootage:
    """The dataset's train footage of ``agent``'s fighter that tracker run ``trained`` finished
    once trained (`train_tracking`), or all of it for a run trained in bouts
    (`train.track.bouts`: it trained on all of it through its matchers, and following a clip as
    filmed is not what it learned); BadInput when it finished none."""
    with connect(db, read_only=True) as con:
        # Agent 0 tracked each clip's fighter and agent 1 the other (`paired_tracking`).
        runs = [c for c in footage_clips(con, trained.dataset_key, ROLES[0]) if len(c.qpos) >= 2]
        finished = clips_finished(con, trained.run_key, "train", agent)
    kept, left = [], []
    for c in runs:
        own, other = (c.qpos, c.other_qpos) if agent == 0 else (c.other_qpos, c.qpos)
        playable = trained.config.track.bouts or finished.get(c.name, False)
        (kept if playable else left).append((c.name, own, other))
    if not kept:
        raise BadInput(
            f"--run {trained.run_key[:12]}",
            f"its tracker finished none of the {len(runs)} train clips of its "
            f"{ROLES[agent]}: no footage it can play",
        )
    return MatchedFootage(tuple(kept), tuple(name for name, _, _ in left))


def footage_replay(trained: TrainedPolicy, clips: Sequence[FootageClip], key: str) -> Played | None:
    """``trained``'s tracker replaying footage ``clips`` (`paired_tracking`: agent 0 tracking
    each clip's fighter, agent 1 the other) from each clip's first frame, both where the
    footage has them (`play_clips`), in the physics its opponent spars in
    (`mujoco_stepping`); None when no clip has two frames."""
    hz = float(trained.config.env.policy_hz)
    data = paired_tracking(clips, trained.bones, fps=hz, key=key)
    if data is None:
        return None
    config = replace(trained.config, env=mujoco_stepping(trained.config.env))
    return play_clips(trained.policy, data, config, as_filmed=True)


def replayed_footage(db: Path, trained: TrainedPolicy, agent: int) -> MatchedFootage:
    """``agent``'s fighter's train footage as tracker run ``trained`` plays it (issue 48's
    physically valid footage; Vid2Player3D cleans a player's video motion by physics imitation
    before matching from it): each clip replayed from its first frame as filmed
    (`footage_replay`), the fighter's simulated qpos after each step with the footage's other
    fighter at the frame it reached, and each step's body error. A replay that fell or drifted
    keeps what came before its last `_FALLING_S`; one left with under 2 frames is left out.
    BadInput when none is left."""
    with connect(db, read_only=True) as con:
        runs = [c for c in footage_clips(con, trained.dataset_key, ROLES[0]) if len(c.qpos) >= 2]
    played = footage_replay(trained, runs, "train")
    if played is None:
        raise BadInput(f"--run {trained.run_key[:12]}", "its dataset has no train footage")
    partners = {c.name: c.other_qpos if agent == 0 else c.qpos for c in runs}
    index = humanoid_index(played.model, prefix=DEFAULT_PREFIXES[agent]).qpos
    falling = round(_FALLING_S * trained.config.env.policy_hz)
    kept, errors, left = [], [], []
    for k, row in enumerate(r for r in played.rows if r.agent == agent):
        # Step t reached the clip's frame t + 1 (`Tracker.step`).
        frames = row.frames if row.finished else row.frames - falling
        if frames < 2:
            left.append(row.clip)
            continue
        other = partners[row.clip][1 : frames + 1]
        kept.append((row.clip, played.qpos[:frames, k][:, index], other))
        errors.append(played.body_error[:frames, k, agent])
    if not kept:
        raise BadInput(
            f"--run {trained.run_key[:12]}",
            f"its tracker's replays of the {len(runs)} train clips of its {ROLES[agent]} all "
            f"fell within {_FALLING_S:g} s: no motion it can play",
        )
    return MatchedFootage(tuple(kept), tuple(left), "replay", tuple(errors))


def trained_policy(db: Path, artifacts: Path, run: str) -> TrainedPolicy:
    """The policy a finished training run (MAAIP's or a tracker's) committed
    (`train_policies`); ``run`` may be a prefix of the run key. BadInput if it matches no
    finished run or several."""
    with connect(db, read_only=True) as con:
        info = finished_run(con, run, "--run")
        metrics = output_metrics(con, "train", info.dataset_key, info.run_key)
    return load_trained(artifacts, info, metrics)


def load_trained(artifacts: Path, info: RunInfo, metrics: dict[str, float]) -> TrainedPolicy:
    """The policy of run ``info`` from its artifact, in eval mode (a tracker's sees the
    tracker's observation, `models.tracking.task`)."""
    config = build(TrainConfig, info.config, section="train")
    policy, bones = checkpoint_policy(read_bytes(artifacts, info.artifact), config)
    return TrainedPolicy(
        info.run_key, info.dataset_key, info.iteration, config, policy, bones, metrics
    )


class _Acting(nn.Module):
    """One agent's deterministic policy: the mean action of its observation (and task)."""

    def __init__(self, policy: Policy, agent: int):
        super().__init__()
        self.policy, self.agent = policy, agent

    def forward(self, observation: torch.Tensor, task: torch.Tensor | None = None):
        return self.policy(observation, self.agent, task)


def policy_onnx(policy: Policy, agent: int) -> bytes:
    """Agent ``agent``'s mean action as an ONNX model (inputs "observation" [, "task"],
    output "action", batch dimension dynamic)."""
    acting = _Acting(policy, agent).eval()
    inputs = [torch.zeros(1, policy.obs_dim)]
    names = ["observation"]
    if policy.task_dim:
        inputs.append(torch.zeros(1, policy.task_dim))
        names.append("task")
    out = io.BytesIO()
    with warnings.catch_warnings():
        # The exporter's deprecation notice and the tracer's notes on the policy's own
        # argument checks (constant for a fixed agent) are not for the user.
        warnings.simplefilter("ignore")
        torch.onnx.export(
            acting,
            tuple(inputs),
            out,
            dynamo=False,
            input_names=names,
            output_names=["action"],
            dynamic_axes={name: {0: "batch"} for name in [*names, "action"]},
            opset_version=ONNX_OPSET,
        )
    return out.getvalue()


def export_opponent(
    out: Path,
    *,
    policy: Policy,
    agent: int,
    bones: tuple[BoneLengths, BoneLengths],
    env: EnvConfig,
    facts: dict,
) -> Path:
    """Write the opponent folder ``out`` (replacing one that is there) and return it.

    Args:
        out: the folder to write.
        policy: the trained shared policy.
        agent: which agent to export (0: the adversary, 1: the other fighter).
        bones: both fighters' bones (agent 0's, agent 1's).
        env: the environment the policy was trained in (rates, fall rule).
        facts: extra manifest entries (keys of the dataset and run, metrics).
    """
    if agent not in (0, 1):
        raise ValueError(f"agent must be 0 or 1, got {agent!r}")
    if policy.obs_dim != OBSERVATION_DIM:
        raise ValueError(f"policy: MAAIP's takes {OBSERVATION_DIM} inputs, got {policy.obs_dim}")
    return _write_folder(
        Path(out),
        maaip.KIND,
        policy=policy,
        agent=agent,
        bones=bones,
        env=env,
        facts=facts,
        # The pose each fighter's mean starts from (`Policy.offset`): where a bout starts.
        guard=action_to_joint_targets(policy.offset[:, : len(HINGE_NAMES)].double().numpy()),
        observation={
            "size": OBSERVATION_DIM,
            "self_blocks": [list(b) for b in SELF_BLOCKS],
            "opponent_blocks": [list(b) for b in OPPONENT_BLOCKS],
            "frame": "the agent's heading frame (MAAIP §4.2); see models/humanoid/observations.py",
        },
        action=_action_layout(),
    )


def _write_folder(
    out: Path,
    kind: str,
    *,
    policy: Policy,
    agent: int,
    bones: tuple[BoneLengths, BoneLengths],
    env: EnvConfig,
    facts: dict,
    guard: np.ndarray,
    observation: dict,
    action: dict,
    extra_files: Mapping[str, bytes] | None = None,
    extra: Mapping[str, object] | None = None,
) -> Path:
    """The folder of one fighter of ``kind``: its policy, the kind's ``extra_files``, the
    humanoid, the arena and the manifest (``extra`` entries before its digests)."""
    files = {
        "policy.onnx": policy_onnx(policy, agent),
        **(extra_files or {}),
        "humanoid.xml": boxer_mjcf(bones[agent]).encode(),
        "arena.xml": arena_mjcf(bones, timestep=env.timestep).encode(),
    }
    manifest = {
        "format": FORMAT,
        "kind": kind,
        "agent": agent,
        "role": "adversary" if agent == 0 else "opponent",
        **facts,
        "bones": [asdict(b) for b in bones],
        "guard": np.asarray(guard, dtype=np.float64).tolist(),
        "env": asdict(env),
        "observation": observation,
        "action": action,
        **(extra or {}),
        "files": _digests(files, kind),
    }
    files[MANIFEST] = (json.dumps(manifest, indent=2) + "\n").encode()
    return write_folder(out, files)


def _digests(files: Mapping[str, bytes], kind: str) -> dict[str, str]:
    return {name: hashlib.sha256(files[name]).hexdigest() for name in KINDS[kind].files}


def _action_layout() -> dict:
    return {
        "size": len(HINGE_NAMES),
        "joints": [{"name": j.name, "dofs": j.dofs} for j in JOINT_LAYOUT],
        "meaning": "PD targets: exponential maps for 3-DoF joints, angles for hinges",
        "actuators": list(HINGE_NAMES),
    }


def deepmimic_clip(assets: Path, name: str, bones: BoneLengths, *, fps: float) -> np.ndarray:
    """DeepMimic's clip ``name`` (`tasks.deepmimic`: CLIPS or WALKER_CLIPS) retargeted onto
    ``bones`` at ``fps``: the qpos (T, 35) a tracker folder plays (`ringside export --clip`)."""
    if name not in (*CLIPS, *WALKER_CLIPS):
        raise BadInput(f"--clip {name}", f"not one of DeepMimic's clips {CLIPS + WALKER_CLIPS}")
    return retarget(load_deepmimic(clip_path(assets, name)), bones, fps=fps)


def export_tracker(
    out: Path,
    *,
    policy: Policy,
    agent: int,
    bones: tuple[BoneLengths, BoneLengths],
    env: EnvConfig,
    clip: tuple[str, np.ndarray],
    facts: dict,
    guard: np.ndarray | None = None,
) -> Path:
    """Write the tracker's opponent folder ``out`` (replacing one that is there) and return it:
    its policy playing ``clip`` (`tasks.opponent.tracker`).

    Args:
        out: the folder to write.
        policy: the trained tracker's policy (451 inputs, `models.tracking.task`).
        agent: which of its agents to export (its arena slot).
        bones: both fighters' bones (agent 0's, agent 1's).
        env: the environment it was trained in (rates, fall rule); the clip is at its rate.
        clip: the clip's name and qpos (T, 35), on ``bones[agent]``, at ``env.policy_hz``.
        facts: extra manifest entries (keys of the dataset and run, metrics).
        guard: (2, 28) where a bout starts each fighter; by default the clip's first frame's
            hinges for the tracker (its replay starts there) and the rest pose for its partner.
    """
    _check_tracker(policy, agent)
    name, qpos = clip
    qpos = np.asarray(qpos, dtype=np.float64)
    if qpos.ndim != 2 or qpos.shape[1] != NQ or len(qpos) < 2 or not np.isfinite(qpos).all():
        raise ValueError(f"clip {name!r}: qpos must be finite, (T >= 2, {NQ}), got {qpos.shape}")
    if guard is None:
        guard = np.zeros((2, len(HINGE_NAMES)))
        guard[agent] = qpos[0, 7:]
    clip_bytes = io.BytesIO()
    np.savez(clip_bytes, **tracker.clip_file(name, qpos, env.policy_hz))
    return _write_folder(
        Path(out),
        tracker.KIND,
        policy=policy,
        agent=agent,
        bones=bones,
        env=env,
        facts=facts,
        guard=guard,
        **_tracker_layouts("the next clip frame's"),
        extra_files={tracker.CLIP: clip_bytes.getvalue()},
        extra={
            "clip": {"name": name, "frames": len(qpos), "fps": env.policy_hz, "file": tracker.CLIP}
        },
    )


def export_matched(
    out: Path,
    *,
    policy: Policy,
    agent: int,
    bones: tuple[BoneLengths, BoneLengths],
    env: EnvConfig,
    footage: MatchedFootage,
    matcher: MatchConfig,
    facts: dict,
) -> Path:
    """Write the matched opponent's folder ``out`` (replacing one that is there) and return it:
    the tracker's policy playing ``clips`` as the matcher picks them (`tasks.opponent.matched`).

    Args:
        out, policy, agent, bones, env, facts: as for `export_tracker`.
        footage: the fighter's motion (`MatchedFootage`): each clip's name, the fighter's qpos
            (T, 35) on ``bones[agent]`` and the other fighter's at the same frames on
            ``bones[1 - agent]``, at ``env.policy_hz``.
        matcher: the matcher's settings.

    A bout starts the fighter at rest in its guard (`guard_pose` over the footage it plays), as
    the evaluation's matched bouts start in the dataset's stance: a pose from mid-stride, held
    at rest, is one it cannot stand in (the demo's matched opponent fell 85 times a minute
    against the still partner from the footage's first frame, 48 from its guard).
    """
    _check_tracker(policy, agent)
    clips = footage.clips
    if not clips:
        raise ValueError("clips: the matched opponent needs footage to play")
    arrays = matched.motion_file(clips, env.policy_hz, footage.body_error)
    # The database the folder will load, made once here: footage it cannot match from (clips
    # too short for the matcher's future, another body's qpos) is refused now, not at load.
    matched.motion_of(arrays, bones[agent], bones[1 - agent], matcher)
    motion = io.BytesIO()
    np.savez(motion, **arrays)
    guard = np.zeros((2, len(HINGE_NAMES)))
    guard[agent] = guard_pose(bones[agent], np.concatenate([np.asarray(c[1]) for c in clips]))
    return _write_folder(
        Path(out),
        matched.KIND,
        policy=policy,
        agent=agent,
        bones=bones,
        env=env,
        facts=facts,
        guard=guard,
        **_tracker_layouts("the matched motion's next frame's"),
        extra_files={matched.MOTION: motion.getvalue()},
        extra={
            "motion": {
                "source": footage.source,
                "clips": len(clips),
                "frames": int(arrays["lengths"].sum()),
                "fps": env.policy_hz,
                "file": matched.MOTION,
            },
            "matcher": matcher.as_dict(),
        },
    )


def _check_tracker(policy: Policy, agent: int) -> None:
    if agent not in (0, 1):
        raise ValueError(f"agent must be 0 or 1, got {agent!r}")
    if policy.obs_dim != TRACK_OBSERVATION_DIM or policy.task_dim:
        raise ValueError(
            f"policy: a tracker's takes {TRACK_OBSERVATION_DIM} inputs and no task, got "
            f"{policy.obs_dim} and {policy.task_dim}"
        )


def _tracker_layouts(frame: str) -> dict[str, dict]:
    """The observation and action entries of a tracker's manifest, ``frame`` naming what the
    tracker is told of (the next clip frame's, the matched motion's next frame's)."""
    return {
        "observation": {
            "size": TRACK_OBSERVATION_DIM,
            "frame": f"o^self, then {frame} (tracking_input); see models/tracking/task.py",
        },
        "action": {
            **_action_layout(),
            "meaning": "a correction added to the PD targets of that frame (DReCon)",
        },
    }


def write_folder(out: Path, files: Mapping[str, bytes]) -> Path:
    """Write ``files`` (name -> bytes) as the folder ``out``, replacing one that is there: staged
    beside it and renamed into place, so a reader never finds half a folder. Returns ``out``."""
    staging = out.with_name(out.name + ".partial")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    for name, data in files.items():
        (staging / name).write_bytes(data)
    if out.exists():
        shutil.rmtree(out)
    staging.rename(out)
    return out


def stored_opponent(artifacts: Path, stored: Mapping[str, str], out: Path) -> Path:
    """The opponent folder an evaluation exported and stored (``stored``: the evaluation's
    artifacts by name, the folder's files as ``opponent/NAME``), written again to ``out``
    without torch. Returns ``out``."""
    prefix = "opponent/"
    files = {
        name.removeprefix(prefix): read_bytes(artifacts, artifact)
        for name, artifact in stored.items()
        if name.startswith(prefix)
    }
    missing = sorted(set((*KINDS[maaip.KIND].files, MANIFEST)) - set(files))
    if missing:
        raise ValueError(f"the evaluation stored no {', '.join(missing)} of its opponent")
    return write_folder(out, files)


def onnx_max_abs_diff(
    policy: Policy,
    agent: int,
    exported: OnnxPolicy,
    observations: np.ndarray,
    task: np.ndarray | None = None,
) -> float:
    """The largest difference between torch's and onnxruntime's actions on observations
    (B, 274) of the agent [and its heading inputs (B, 2)] (the export's parity check of an
    exported MAAIP policy, ``exported``)."""
    obs = np.asarray(observations, dtype=np.float32)
    given = None if task is None else np.asarray(task, dtype=np.float32)
    with torch.no_grad():
        expected = _Acting(policy, agent)(
            torch.from_numpy(obs), None if given is None else torch.from_numpy(given)
        ).numpy()
    return float(np.abs(exported.actions(obs, given) - expected).max())
