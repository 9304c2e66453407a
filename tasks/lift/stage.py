"""The lift stage: both fighters' 2D keypoints become humanoid motions in one world.

Per shot: the camera and floor come from the fighters' own bodies (:func:`ground_fighters`),
each fighter is lifted to 3D joints (:func:`lift_fighter`), fitted with a humanoid scaled to
its measured bones (:func:`fit_humanoid`) and cleaned up in MuJoCo against the floor and the
other fighter (:func:`cleanup`). The cleaned motion is stored on the 30 Hz grid
(:func:`resample`) and rendered, both humanoids together, to the review video (:func:`render_lift`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import mujoco
import numpy as np

from models.humanoid.boxer import BoneLengths, single_scene_mjcf
from models.humanoid.fitting import fit_humanoid
from models.humanoid.kinematics import NQ
from models.humanoid.motion import RATE, FighterMotion, fighter_distance
from storage.artifacts import artifact_name
from storage.files import scratch_dir
from storage.keys import code_version
from tasks.errors import BadInput
from tasks.lift.camera import (
    Camera,
    fov_intrinsics,
    ground_fighters,
    read_calibration,
    root_translations,
    stature_notes,
    undistort,
)
from tasks.lift.cleanup import Cleaned, cleanup, cleanup_pair, floor_depth
from tasks.lift.config import LiftStageConfig
from tasks.lift.gates import (
    REASONS,
    GateConfig,
    depth_jumps,
    floating,
    one_person,
    shot_problem,
    too_far,
    too_fast,
)
from tasks.lift.gates import notes as gate_notes
from tasks.lift.lifting import Lifted3D, lift_fighter
from tasks.lift.metrics import HIPS, bone_length_std_mm
from tasks.lift.resample import resample
from tasks.lift.series import cleanup_series, motion_columns
from tasks.lift.store import CameraRow, MediaRow, bone_rows
from tasks.media import render_lift
from tasks.roles import ROLES
from tasks.runner import StageOutput, StageSpec

STAGE = "lift"


def lift_code() -> str:
    return code_version("tasks.lift", "tasks.media", "models.humanoid", "models.arena.mjcf")


def lift_spec(
    config: LiftStageConfig, video_id: str, pose_key: str, calibration_sha: str | None
) -> StageSpec:
    upstream = {"pose": pose_key, "calibration": calibration_sha}
    return StageSpec(STAGE, video_id, config, lift_code(), upstream)


@dataclass(frozen=True, eq=False)
class FighterTrack:
    """One fighter's 2D input over the video. F frames of the video."""

    keypoints: np.ndarray  # (F, 33, 2) pixels, NaN where unseen
    confidence: np.ndarray  # (F, 33)
    world: np.ndarray  # (F, 33, 3) BlazePose world landmarks, NaN where unseen


def fighter_tracks(columns: Mapping[str, np.ndarray], frames: int) -> dict[str, FighterTrack]:
    """Dense per-fighter arrays from ``pose_keypoints`` columns (role, frame, x, y, confidence,
    world, track; as DuckDB's ``fetchnumpy`` or the pose stage's own rows give them)."""
    fighters = {}
    roles = np.asarray(columns["role"])
    for role in ROLES:
        mine = roles == role
        if not mine.any():
            continue
        at = np.asarray(columns["frame"])[mine].astype(np.int64)
        pick = np.flatnonzero(mine)
        keypoints = np.full((frames, 33, 2), np.nan)
        confidence = np.zeros((frames, 33))
        world = np.full((frames, 33, 3), np.nan)
        keypoints[at, :, 0] = np.stack([columns["x"][i] for i in pick])
        keypoints[at, :, 1] = np.stack([columns["y"][i] for i in pick])
        confidence[at] = np.stack([columns["confidence"][i] for i in pick])
        world[at] = np.stack([columns["world"][i] for i in pick]).reshape(-1, 33, 3)
        # Frames the pose stage filled in without seeing the fighter carry no world landmarks.
        world[at[np.asarray(columns["track"])[mine] < 0]] = np.nan
        fighters[role] = FighterTrack(keypoints, confidence, world)
    return fighters


def _segment(track: FighterTrack, start: int, end: int, min_frames: int) -> tuple[int, int] | None:
    """The span [first, last + 1) of frames in [start, end) where the fighter is seen, if long
    enough to lift."""
    # Seen = observed by the pose stage (its world landmarks exist); single 2D joints may still
    # be NaN where refinement did not trust them, which the lift takes as missing.
    seen = np.flatnonzero(np.isfinite(track.world[start:end]).all(axis=(1, 2)))
    if len(seen) < min_frames:
        return None
    return start + int(seen[0]), start + int(seen[-1]) + 1


# The least height in pixels (top to bottom of a fighter's keypoints, median over the frames
# the pose stage saw them) at which people were lifted. Measured on the bundled sample (two people
# walking, 1088x1920, ~820 px tall) shrunk by 0.10-0.30 onto a grey canvas of its own size and
# run with `ringside process --until lift`: people a median 90 and 110 px tall were seen but
# not lifted (each shot left out: their sizes are too noisy to place them, which put the
# fighters 10-15 m apart); 128, 135, 178 and 263 px were lifted. Below about 90 px (shrunk by
# 0.09 or less) the person detector finds nobody, and the pose stage refuses the video.
MIN_PERSON_PX = 125


def median_height_px(fighters: Mapping[str, FighterTrack]) -> float | None:
    """The fighters' median height in the image, pixels: top to bottom of their keypoints on
    each frame the pose stage saw them; None if it saw neither."""
    heights = []
    for track in fighters.values():
        seen = np.isfinite(track.world).all(axis=(1, 2))
        y = track.keypoints[seen][..., 1]
        y = y[np.isfinite(y).any(axis=1)]
        heights.append(np.nanmax(y, axis=1) - np.nanmin(y, axis=1))
    found = np.concatenate(heights) if heights else np.zeros(0)
    return float(np.median(found)) if len(found) else None


def _intrinsics(
    config: LiftStageConfig, size: tuple[int, int], calibration: Path | None
) -> tuple[np.ndarray, np.ndarray, str]:
    """K, the lens distortion (zeros when guessed) and where they came from."""
    if calibration is None:
        return fov_intrinsics(*size, config.fov_deg), np.zeros(5), "fov"
    K, dist, calibrated_size = read_calibration(calibration)
    if calibrated_size != tuple(size):
        raise BadInput(
            str(calibration),
            f"was made for {calibrated_size[0]}x{calibrated_size[1]} "
            f"images, but the video is {size[0]}x{size[1]}",
        )
    return K, dist, "calibration"


def _without_distortion(track: FighterTrack, K: np.ndarray, dist: np.ndarray) -> FighterTrack:
    """The track as a pinhole camera would have seen it: the lift's projection has no lens."""
    if not np.any(dist):
        return track
    return dataclasses.replace(track, keypoints=undistort(track.keypoints, K, dist))


def _median_distance(spans: dict[str, tuple[int, int]], roots: list[np.ndarray]) -> float | None:
    """Median distance (m) between the two fighters' placed pelvises over the frames both are
    seen; None with fewer than two fighters or no shared frame."""
    if len(spans) < 2:
        return None
    (a0, b0), (a1, b1) = spans.values()
    lo, hi = max(a0, a1), min(b0, b1)
    if hi <= lo:
        return None
    gap = np.linalg.norm(roots[0][lo - a0 : hi - a0] - roots[1][lo - a1 : hi - a1], axis=-1)
    gap = gap[np.isfinite(gap)]
    return float(np.median(gap)) if len(gap) else None


def _gate_placement(
    track: FighterTrack, a: int, b: int, K: np.ndarray, gates: GateConfig, refused: np.ndarray
) -> tuple[FighterTrack, np.ndarray, np.ndarray]:
    """The track with the frames of [a, b) refused (as unseen) that ``refused`` (F,) names or
    whose metric skeleton, placed along the camera rays (`root_translations`), lies too far
    away or jumps in depth: such frames would bend the floor and the lift of every other
    frame. Returns the gated track (a copy) and the masks over the whole video, (F,) far and
    (F,) fast."""
    roots = np.full((len(track.keypoints), 3), np.nan)
    roots[a:b] = root_translations(track.keypoints[a:b], track.confidence[a:b], track.world[a:b], K)
    far = np.zeros(len(roots), bool)
    fast = np.zeros(len(roots), bool)
    far[a:b] = too_far(roots[a:b], np.zeros(3), gates)
    fast[a:b] = depth_jumps(roots[a:b], gates)
    bad = far | fast | refused
    keypoints, confidence, world = (
        track.keypoints.copy(),
        track.confidence.copy(),
        track.world.copy(),
    )
    keypoints[bad], confidence[bad], world[bad] = np.nan, 0.0, np.nan
    return FighterTrack(keypoints, confidence, world), far, fast


def _believed(
    lifted: Lifted3D, good: np.ndarray, min_frames: int
) -> tuple[int, Lifted3D, np.ndarray] | None:
    """The lifted span trimmed to its first and last believed frame, with the points of the
    frames in between that are not believed drawn straight from their believed neighbours (so
    the humanoid fit and the cleanup never see them; they are dropped after). Returns the
    offset of the first frame kept, the trimmed motion and its believed mask; None when fewer
    than ``min_frames`` frames are believed."""
    kept = np.flatnonzero(good)
    if len(kept) < min_frames:
        return None
    first, last = int(kept[0]), int(kept[-1]) + 1
    points = lifted.points[first:last].copy()
    mask = good[first:last]
    frames = np.arange(len(points))
    flat = points.reshape(len(points), -1)
    for column in range(flat.shape[1]):
        flat[~mask, column] = np.interp(frames[~mask], frames[mask], flat[mask, column])
    trimmed = dataclasses.replace(
        lifted,
        points=flat.reshape(points.shape),
        contacts=lifted.contacts[first:last] & mask[:, None],
    )
    return first, trimmed, mask


def _clean_shot(fitted: dict, fps: float, config: LiftStageConfig) -> dict[str, Cleaned]:
    """Each fitted fighter of a shot cleaned up in MuJoCo, the two together when both are there.

    ``fitted`` maps role to (first frame, end frame, Lifted3D, qpos). Each is cleaned over its
    own frames; where the other is not seen, it stands parked far away.
    """
    models = {
        role: mujoco.MjModel.from_xml_string(single_scene_mjcf(lifted.bones))
        for role, (_, _, lifted, _) in fitted.items()
    }
    if len(fitted) == 1:
        ((role, (_, _, lifted, fit)),) = fitted.items()
        return {role: cleanup(models[role], fit, lifted.contacts, fps=fps, config=config.solve)}
    roles = list(fitted)
    pair = cleanup_pair(
        tuple(models[r] for r in roles),
        tuple(fitted[r][3] for r in roles),
        tuple(fitted[r][2].contacts for r in roles),
        fps=fps,
        config=config.solve,
        spans=tuple((fitted[r][0], fitted[r][1]) for r in roles),
    )
    return dict(zip(roles, pair, strict=True))


@dataclass(frozen=True, eq=False)
class FighterShot:
    """One fighter's lift over one shot: frames [start, start + len(cleaned.qpos))."""

    start: int
    cleaned: Cleaned
    dropped: np.ndarray  # (n,) frames the cleanup's gates drop
    bones: BoneLengths
    bone_length_std_mm: float
    cleanup_change_mm: float
    cleanup_metrics: dict[str, float]


@dataclass(frozen=True, eq=False)
class ShotLift:
    """One shot's lift: its camera (None when the shot is left out), each fighter lifted in
    it, the frames each gate rejected, the frames a fighter was seen, and notes."""

    shot: int
    camera: Camera | None
    fighters: dict[str, FighterShot]
    rejected: dict[str, int]
    seen_frames: int
    notes: tuple[str, ...]


@dataclass(frozen=True, eq=False)
class Lift:
    """A video's lift, before it becomes the stage's rows (`lift_output`).

    cameras: (shot, where K came from: 'fov' or 'calibration', camera) of each lifted shot;
    motion: each lifted fighter's cleaned motion on the 30 Hz grid; bones: each one's bone
    lengths (from its longest lifted span); cut_steps: the first grid step of each shot after
    the first.
    """

    cameras: list[tuple[int, str, Camera]]
    motion: dict[str, FighterMotion]
    bones: dict[str, BoneLengths]
    cut_steps: list[int]
    metrics: dict[str, float]
    notes: tuple[str, ...]


def lift_shot(
    fighters: Mapping[str, FighterTrack],
    twice: np.ndarray,
    shot: int,
    start: int,
    end: int,
    *,
    K: np.ndarray,
    size: tuple[int, int],
    fps: float,
    config: LiftStageConfig,
) -> ShotLift:
    """Lift the fighters over frames [start, end) of one shot: place the camera from their
    bodies, lift and fit each, clean them up together. ``twice`` (F,) marks the frames where
    both roles are on one person (`one_person`)."""
    gates = config.gates
    rejected = dict.fromkeys(REASONS, 0)
    seen_frames = 0
    gated, refused, spans = {}, {}, {}
    for role, track in fighters.items():
        seen = _segment(track, start, end, config.min_frames)
        if seen is None:
            continue
        seen_frames += seen[1] - seen[0]
        gated[role], far, fast = _gate_placement(track, *seen, K, gates, twice)
        refused[role] = twice | far | fast
        rejected["one_person"] += int(twice[seen[0] : seen[1]].sum())
        rejected["depth"] += int((far & ~twice).sum())
        rejected["speed"] += int((fast & ~far & ~twice).sum())
        span = _segment(gated[role], start, end, config.min_frames)
        if span is None:
            rejected["short"] += int((seen[1] - seen[0]) - refused[role].sum())
            continue
        spans[role] = span
    if not spans:
        return ShotLift(shot, None, {}, rejected, seen_frames, ())
    inputs = {
        r: (gated[r].keypoints[a:b], gated[r].confidence[a:b], gated[r].world[a:b])
        for r, (a, b) in spans.items()
    }
    # Known statures set the scene's metric scale (BlazePose's is an average body's).
    known = [config.statures()[r] for r in inputs]
    camera, roots, scales = ground_fighters(list(inputs.values()), K, size, known)
    inputs = {r: (k, c, w * s) for (r, (k, c, w)), s in zip(inputs.items(), scales, strict=True)}
    problem = shot_problem(float(camera.centre[2]), _median_distance(spans, roots), gates)
    if problem is not None:
        rejected["shot"] += sum(b - a for a, b in spans.values())
        note = f"shot {shot} left out: {problem}"
        return ShotLift(shot, None, {}, rejected, seen_frames, (note,))
    fitted, believed = {}, {}
    for (role, (a, b)), root in zip(spans.items(), roots, strict=True):
        lifted = lift_fighter(
            *inputs[role],
            camera.K,
            camera.R,
            camera.t,
            fps=fps,
            config=config.solve,
            root_init=root,
        )
        hips = lifted.points[:, list(HIPS)].mean(1)
        far, fast = too_far(hips, camera.centre, gates), too_fast(hips, fps, gates)
        earlier = refused[role][a:b]  # refused before the lift, which bridged them
        far, fast = far & ~earlier, fast & ~far & ~earlier
        rejected["depth"] += int(far.sum())
        rejected["speed"] += int(fast.sum())
        kept = _believed(lifted, ~(far | fast | earlier), config.min_frames)
        if kept is None:
            rejected["short"] += int((~far & ~fast & ~earlier).sum())
            continue
        first, lifted, believed[role] = kept
        a, b = a + first, a + first + len(lifted.points)
        fitted[role] = (
            a,
            b,
            lifted,
            fit_humanoid(
                lifted.points,
                lifted.bones,
                iterations=config.solve.ik_iterations,
                damping=config.solve.ik_damping,
                face_weight=config.solve.ik_face_weight,
            ),
        )
    lifted_fighters = {}
    if fitted:
        for role, cleaned in _clean_shot(fitted, fps, config).items():
            a, _, lifted, _ = fitted[role]
            fine = believed[role]
            high = floating(cleaned.settle, gates) & fine
            fast = too_fast(cleaned.qpos[:, :3], fps, gates) & fine & ~high
            rejected["floating"] += int(high.sum())
            rejected["speed"] += int(fast.sum())
            model = mujoco.MjModel.from_xml_string(single_scene_mjcf(lifted.bones))
            sunk = floor_depth(model, cleaned.qpos)
            lifted_fighters[role] = FighterShot(
                start=a,
                cleaned=cleaned,
                dropped=high | fast | ~fine,
                bones=lifted.bones,
                bone_length_std_mm=bone_length_std_mm(lifted.points),
                cleanup_change_mm=float(
                    np.nanmean(np.linalg.norm(cleaned.points - lifted.points, axis=-1)) * 1000
                ),
                cleanup_metrics={
                    **cleaned.metrics,
                    "floor_penetration_mean_mm": float(sunk.mean() * 1000),
                },
            )
    if not any((~f.dropped).any() for f in lifted_fighters.values()):
        # Every step refused after the camera was placed: the shot is left out like one whose
        # fighters were never lifted, so that the video's refusal names why (tiny people on one
        # CPU got a camera and no step, and the media stage failed on an empty motion).
        return ShotLift(shot, None, {}, rejected, seen_frames, ())
    return ShotLift(shot, camera, lifted_fighters, rejected, seen_frames, ())


def lift_video(
    fighters: Mapping[str, FighterTrack],
    *,
    fps: float,
    size: tuple[int, int],
    shots: list[tuple[int, int, int]],
    config: LiftStageConfig,
    calibration: Path | None,
    progress: Callable[[int], None] | None = None,
) -> Lift:
    """Lift every shot of a video (`lift_shot`) and put the shots' motions on one grid.

    ``fighters`` maps role to its 2D input; ``shots`` are (shot, start, end) frame ranges.
    ``progress(frames)`` is told each shot's frames once the shot is done.
    Raises :class:`BadInput` when no shot is lifted: when a fighter was seen long enough but
    the fighters are smaller than people are lifted (`MIN_PERSON_PX`), saying so with their
    median height; when the gates left every shot out, with their reasons; else that no
    fighter is seen long enough in any shot.
    """
    advance = progress or (lambda frames: None)
    frames = next(iter(fighters.values())).keypoints.shape[0]
    K, dist, source = _intrinsics(config, size, calibration)
    fighters = {r: _without_distortion(track, K, dist) for r, track in fighters.items()}
    twice = np.zeros(frames, bool)
    if all(r in fighters for r in ROLES):
        twice = one_person(*(fighters[r].keypoints for r in ROLES), config.gates)
    lifted: list[ShotLift] = []
    for shot, start, end in shots:
        lifted.append(
            lift_shot(fighters, twice, shot, start, end, K=K, size=size, fps=fps, config=config)
        )
        advance(end - start)
    notes = [note for one in lifted for note in one.notes]
    fighter_frames = sum(one.seen_frames for one in lifted)
    rejected = {reason: sum(one.rejected[reason] for one in lifted) for reason in REASONS}
    cameras = [(one.shot, source, one.camera) for one in lifted if one.camera is not None]
    if not cameras:
        # Seen long enough (fighter_frames), yet no shot lifted: their size may be why.
        tall = median_height_px(fighters) if fighter_frames else None
        if tall is not None and tall < MIN_PERSON_PX:
            left_out = f" ({'; '.join(notes)})" if notes else ""
            raise BadInput(
                STAGE,
                f"the people found are a median {tall:.0f} px tall, too small to lift: "
                f"on the bundled sample, people under about {MIN_PERSON_PX} px were not "
                f"lifted{left_out}",
            )
        if notes:  # seen, but every shot was left out by a gate: say which and why
            raise BadInput(STAGE, f"no shot could be lifted: {'; '.join(notes)}")
        raise BadInput(
            STAGE,
            f"no fighter is seen in {config.min_frames} frames of any shot "
            f"(lift.min_frames); nothing to lift",
        )

    parts = {r: [one.fighters[r] for one in lifted if r in one.fighters] for r in fighters}
    grids = {role: _on_grid(mine, frames) for role, mine in parts.items()}
    qpos = {role: grid.qpos for role, grid in grids.items()}
    # Each fighter's bones are those of its longest lifted span.
    bones = {
        r: max(mine, key=lambda p: len(p.cleaned.qpos)).bones for r, mine in parts.items() if mine
    }
    metrics = _metrics(qpos, parts)
    metrics.update({f"frames_rejected_{reason}": float(n) for reason, n in rejected.items()})
    metrics["frames_rejected"] = float(sum(rejected.values()))
    notes += gate_notes(rejected, fighter_frames, config.gates)
    notes += stature_notes(config.statures(), {r: grids[r].joints for r in bones})
    # Each shot has its own camera and world: nothing on the grid is taken across a cut.
    cuts = sorted(start for _, start, _ in shots if start > 0)
    motion = {
        role: resample(
            qpos[role],
            grids[role].joints,
            grids[role].contacts,
            fps=fps,
            rate=RATE,
            bones=bones[role],
            cuts=cuts,
        )
        for role in bones
    }
    return Lift(
        cameras,
        motion,
        bones,
        [math.ceil(c / fps * RATE - 1e-9) for c in cuts],
        metrics,
        tuple(notes),
    )


class _Grid(NamedTuple):
    """A fighter's shots on the video's frames: qpos (F, NQ), joints (F, 33, 3) and foot
    contacts (F, 2); NaN (no contact) where it is not lifted or a gate dropped it. The lift
    stores positions only: `resample` takes the velocities anew on its grid."""

    qpos: np.ndarray
    joints: np.ndarray
    contacts: np.ndarray


def _on_grid(parts: Sequence[FighterShot], frames: int) -> _Grid:
    grid = _Grid(
        np.full((frames, NQ), np.nan), np.full((frames, 33, 3), np.nan), np.zeros((frames, 2), bool)
    )
    for part in parts:
        a, b = part.start, part.start + len(part.cleaned.qpos)
        grid.qpos[a:b], grid.joints[a:b] = part.cleaned.qpos, part.cleaned.points
        grid.contacts[a:b] = part.cleaned.contacts
        for array in (grid.qpos, grid.joints):
            array[a:b][part.dropped] = np.nan
        grid.contacts[a:b][part.dropped] = False
    return grid


def lift_output(lift: Lift) -> StageOutput:
    """The lift output's rows, and its review video (both humanoids, `render_lift`) as the
    file the runner stores."""
    with scratch_dir("lift") as tmp:
        path = Path(tmp) / "lift.mp4"
        render_lift(lift.motion, path)
        video = path.read_bytes()
    name = artifact_name(video, ".mp4")
    series = cleanup_series(lift.motion, cuts=lift.cut_steps)
    rows = {
        "lift_cameras": [
            CameraRow(
                shot,
                source,
                camera.K.ravel().tolist(),
                camera.R.ravel().tolist(),
                camera.t.tolist(),
                float(camera.centre[2]),
                _pitch_deg(camera),
            )
            for shot, source, camera in lift.cameras
        ],
        "lift_motion": motion_columns(lift.motion, series),
        "lift_bones": bone_rows(lift.bones),
        "lift_media": [MediaRow("video", name)],
    }
    return StageOutput(rows, lift.metrics, lift.notes, files={name: video})


def _pitch_deg(camera: Camera) -> float:
    """How far the camera looks down from the horizon, degrees."""
    forward_world = camera.R[2]  # the camera's z axis in world coordinates
    return float(math.degrees(math.asin(-np.clip(forward_world[2], -1, 1))))


# Names the cleanup reports -> the stage's metric names (max over shots for maxima).
_CLEANUP_NAMES = {
    "floor_penetration_mm_after": "floor_penetration_max_mm",
    "floor_penetration_mm_before": "floor_penetration_max_mm_before",
    "interpenetration_mm_after": "inter_fighter_penetration_max_mm",
    "interpenetration_mm_before": "inter_fighter_penetration_max_mm_before",
    "foot_skating_cm_per_frame_after": "foot_skating_cm_per_frame",
    "foot_skating_cm_per_frame_before": "foot_skating_cm_per_frame_before",
    "jitter_m_s2_after": "jitter_m_s2",
    "jitter_m_s2_before": "jitter_m_s2_before",
    "contact_slide_cm_per_frame_after": "contact_slide_cm_per_frame",
    "contact_slide_cm_per_frame_before": "contact_slide_cm_per_frame_before",
    "contact_share": "contact_share",
    "foot_height_cm_after": "foot_height_median_cm",
    "foot_height_cm_before": "foot_height_median_cm_before",
    "floor_settle_cm": "floor_settle_cm",
    "floor_penetration_mean_mm": "floor_penetration_mean_mm",
}


def _metrics(
    qpos: Mapping[str, np.ndarray], shots: Mapping[str, Sequence[FighterShot]]
) -> dict[str, float]:
    """Per fighter (prefixed with its role) and, unprefixed, the worst of the two fighters."""
    metrics: dict[str, float] = {}
    worst: dict[str, float] = {}
    for role, parts in shots.items():
        if not parts:
            continue
        merged = {}
        for source, name in _CLEANUP_NAMES.items():
            values = [
                p.cleanup_metrics[source]
                for p in parts
                if np.isfinite(p.cleanup_metrics.get(source, np.nan))
            ]
            if values:
                merged[name] = max(values) if "max" in name else float(np.mean(values))
        merged["bone_length_std_mm"] = float(np.mean([p.bone_length_std_mm for p in parts]))
        merged["cleanup_change_mm"] = float(np.mean([p.cleanup_change_mm for p in parts]))
        merged["frames_lifted"] = float(np.isfinite(qpos[role]).all(axis=1).sum())
        for name, value in merged.items():
            metrics[f"{role}_{name}"] = value
            if name != "frames_lifted":
                worst[name] = max(worst.get(name, -np.inf), value)
    metrics.update(worst)
    if all(r in qpos for r in ROLES):
        both = np.isfinite(qpos["adversary"]).all(1) & np.isfinite(qpos["opponent"]).all(1)
        if both.any():
            gap = fighter_distance(qpos["adversary"][both], qpos["opponent"][both])
            metrics["fighter_distance_mean_m"] = float(gap.mean())
    return {k: float(v) for k, v in metrics.items() if np.isfinite(v)}
