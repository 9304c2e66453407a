"""The pose stage: a registered video becomes both fighters' tracks and refined 2D keypoints.

Chunks of frames are detected, tracked and estimated on their own (:func:`process_chunk`, the
costly part, cached per chunk); :func:`assemble` joins them, picks the two fighters and their
roles, refines each fighter's keypoints over time and measures the result.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from models.pose.tiling import TiledDetector
from models.pose.types import BLAZEPOSE_33, BLAZEPOSE_TO_COCO17, COCO_17, Detector, PoseEstimator
from storage.artifacts import artifact_name
from storage.files import scratch_dir
from storage.keys import code_version, digest
from tasks.errors import BadInput
from tasks.media import H264Writer
from tasks.pose.chunk import ChunkTracks, track_chunk
from tasks.pose.config import FighterConfig, PoseConfig
from tasks.pose.fighters import (
    PairScore,
    adversary_by_colour,
    choice_margin,
    link_fragments,
    pick_fighters,
    rank_pairs,
)
from tasks.pose.frames import read_frames
from tasks.pose.merge import ChunkSpan, VideoTracks, merge_chunks, summaries
from tasks.pose.overlay import draw_people, overlay_size
from tasks.pose.people_tracking import colour_distance
from tasks.pose.refine import flip_bones, flip_groups, flip_permutation, refine
from tasks.pose.store import MediaRow, TrackRow
from tasks.roles import ROLES
from tasks.runner import StageOutput, StageSpec

STAGE = "pose"
# A chosen pair whose boxes sit on one body in more than this share of their frames together
# gets a note (`PairScore.one_body`).
ONE_BODY_NOTE = 0.1
JOINTS = len(BLAZEPOSE_33)
# Settings that change what happens after the chunks, not inside them.
NOT_IN_CHUNKS = (
    "refine",
    "fighters",
    "min_fighter_share",
    "link_gap_s",
    "overlay_seconds",
    "overlay_max_side",
    "stills",
    "workers",
)


def pose_code() -> str:
    return code_version("tasks.pose", "tasks.media", "models.pose")


def pose_spec(config: PoseConfig, video_id: str, ingest_key: str, pick: int | None) -> StageSpec:
    return StageSpec(STAGE, video_id, config, pose_code(), {"ingest": ingest_key, "pick": pick})


def chunk_key(config: PoseConfig, video_id: str, span: ChunkSpan, models: tuple[str, str]) -> str:
    """Key of one chunk's tracks: its frames, the settings that act inside chunks and the
    SHA-256 of the two model files (new weights at the same path are new work)."""
    settings = {k: v for k, v in dataclasses.asdict(config).items() if k not in NOT_IN_CHUNKS}
    return digest(
        {"video": video_id, "span": span, "config": settings, "models": models, "code": pose_code()}
    )[:24]


def plan_spans(
    chunks: list[tuple[int, int, int, int]],
    overlap: int,
    source_frames: Sequence[int] | None = None,
) -> list[ChunkSpan]:
    """Spans for ingest's chunks ``(index, shot, start, end)``: a chunk continuing its shot
    re-reads ``overlap`` frames before its start. ``source_frames``: ingest's re-timing of a
    variable-rate video, each span's part of it goes with the span (and into its key)."""
    spans, previous_shot = [], None
    for index, shot, start, end in sorted(chunks):
        read_start = max(0, start - overlap) if shot == previous_shot else start
        source = None if source_frames is None else tuple(source_frames[read_start:end])
        spans.append(ChunkSpan(index, shot, start, end, read_start, source))
        previous_shot = shot
    return spans


@dataclass(frozen=True)
class Backend:
    """A pose backend: its default model files (under the assets folder; empty for none) and
    how to build its detector and estimator from two model files."""

    default_detector: str
    default_pose: str
    build: Callable[[Path, Path, PoseConfig], tuple[Detector, PoseEstimator]]


def _blazepose(detector: Path, pose: Path, config: PoseConfig) -> tuple[Detector, PoseEstimator]:
    from models.pose.blazepose import BlazePoseDetector, BlazePoseLandmarker

    return (
        BlazePoseDetector(
            detector, score_threshold=config.detection_score, num_threads=config.num_threads
        ),
        BlazePoseLandmarker(pose, num_threads=config.num_threads),
    )


def _onnx(detector: Path, pose: Path, config: PoseConfig) -> tuple[Detector, PoseEstimator]:
    from models.pose.onnx_backend import OnnxDetector, OnnxPoseEstimator

    return (
        OnnxDetector(
            detector, score_threshold=config.detection_score, num_threads=config.num_threads
        ),
        OnnxPoseEstimator(pose, num_threads=config.num_threads),
    )


BACKENDS: Mapping[str, Backend] = {
    "blazepose": Backend("pose_detection.tflite", "pose_landmark_full.tflite", _blazepose),
    "onnx": Backend("", "", _onnx),
}


def model_files(config: PoseConfig, assets: Path) -> tuple[Path, Path]:
    """The detector and pose model files the config names, checked to exist."""
    backend = BACKENDS[config.backend]
    found = []
    for setting, configured, default in (
        ("pose.detector_model", config.detector_model, backend.default_detector),
        ("pose.pose_model", config.pose_model, backend.default_pose),
    ):
        path = Path(configured) if configured else assets / default
        if not path.is_file():
            hint = "check the path" if configured else "run `ringside assets pull`"
            raise BadInput(setting, f"model file {path} not found ({hint})")
        found.append(path)
    return found[0], found[1]


def process_chunk(
    video: Path, span: ChunkSpan, fps: float, config: PoseConfig, models: tuple[Path, Path]
) -> ChunkTracks:
    """Detect, follow, track and estimate everyone in one chunk of ``video``."""
    detector, estimator = BACKENDS[config.backend].build(*models, config)
    detector = TiledDetector(detector, config.detector_tiles)
    return track_chunk(
        read_frames(video, span.read_start, span.end, span.source),
        start=span.read_start,
        end=span.end,
        fps=fps,
        detector=detector,
        estimator=estimator,
        config=config,
    )


@dataclass(frozen=True)
class ShotChoice:
    """How the fighters of one shot were chosen: the ranked candidate pairs (`rank_pairs`,
    best first; the best is the fighters unless the analyst picked otherwise) and the shot's
    frames."""

    shot: int
    frames: int
    ranked: tuple[PairScore, ...]


@dataclass(frozen=True)
class Roles:
    """Each track's role, how the adversary was told apart, and how the fighters were chosen."""

    by_track: dict[int, str]
    source: str  # 'pick', 'colour' or 'guess'
    choices: tuple[ShotChoice, ...] = ()

    def choice_metrics(self) -> dict[str, float]:
        """Over the shots with a candidate pair, weighted by their frames: how clearly the
        chosen pair beat the next (`choice_margin`) and the share of frames it was seen
        together in."""
        chosen = [c for c in self.choices if c.ranked]
        weights = np.array([c.frames for c in chosen], dtype=float)
        if not chosen or weights.sum() <= 0:
            return {}
        found = {
            "fighters_together_share": float(
                np.average([c.ranked[0].together for c in chosen], weights=weights)
            ),
            "fighters_one_body_share": float(
                np.average([c.ranked[0].one_body for c in chosen], weights=weights)
            ),
        }
        # A shot where only one pair qualified has no margin (NaN): it is left out, and the
        # metric is absent when no shot had a second pair.
        margins = np.array([choice_margin(list(c.ranked)) for c in chosen])
        known = np.isfinite(margins) & (weights > 0)
        if known.any():
            found["fighter_choice_margin"] = float(
                np.average(margins[known], weights=weights[known])
            )
        return found

    def choice_notes(self, min_together: float, min_margin: float) -> list[str]:
        """A note per shot whose chosen pair is unconvincing: seen together in less than
        ``min_together`` of its frames (a crowd, one person, passers-by), or barely better than
        the next pair; naming the next candidates for `ringside pick`."""
        notes = []
        for choice in self.choices:
            if not choice.ranked:
                continue
            best, others = choice.ranked[0], choice.ranked[1:3]
            if best.one_body > ONE_BODY_NOTE:
                notes.append(
                    f"shot {choice.shot}: the fighters (tracks {best.track_ids[0]} and "
                    f"{best.track_ids[1]}) sit on one body in {best.one_body:.0%} of the frames "
                    "they are seen together: they may be one person tracked twice. Check the "
                    "overlay, and set the adversary with `ringside pick`"
                )
            margin = choice_margin(list(choice.ranked))
            # With a single candidate pair there is no margin (NaN): not "barely better".
            if best.together >= min_together and not margin < min_margin:
                continue
            why = (
                f"seen together in only {best.together:.0%} of its frames"
                if best.together < min_together
                else f"barely better than the next pair (margin {margin:.0%})"
            )
            nexts = "; ".join(
                f"tracks {p.track_ids[0]} and {p.track_ids[1]} (score {p.score:.2f})"
                for p in others
            )
            hint = f"; next candidates: {nexts}" if nexts else ""
            notes.append(
                f"shot {choice.shot}: the fighters (tracks {best.track_ids[0]} and "
                f"{best.track_ids[1]}) are {why}; this may not be two people fighting. "
                f"Check the overlay, and set the adversary with `ringside pick`{hint}"
            )
        return notes


def assign_roles(
    tracks: VideoTracks,
    *,
    shot_frames: Mapping[int, int],
    frame_size: tuple[int, int],
    colour: str | None,
    pick: int | None,
    min_share: float,
    link_gap_frames: int,
    config: FighterConfig,
) -> Roles:
    """Choose the two fighters in every shot and say which one is the adversary.

    Within a shot, tracks that are one person lost for up to ``link_gap_frames`` are joined
    first (:func:`link_fragments`), so a fighter hidden for a while is still one fighter. The
    analyst's pick wins; else the declared colour; else, in later shots, whoever looks most like
    the adversary of the first shot; else (no pick, no colour) the first fighter found is taken
    as the adversary and the source says it is a guess, in every shot the guess is carried to.
    """
    all_tracks = {s.track_id: s for s in summaries(tracks)}
    if pick is not None and pick not in all_tracks:
        raise BadInput("pick", f"track {pick} does not exist; tracks are {sorted(all_tracks)}")
    roles = {t: "other" for t in all_tracks}
    choices: list[ShotChoice] = []
    reference: dict[str, np.ndarray] = {}
    source = "pick" if pick is not None else "colour" if colour else "guess"
    shots = sorted(set(tracks.track_shot[list(all_tracks)].tolist())) if all_tracks else []
    # The picked track's shot goes first, so its fighters are the appearance reference.
    if pick is not None:
        shots.sort(key=lambda s: s != tracks.track_shot[pick])
    for shot in shots:
        pieces = [s for t, s in all_tracks.items() if tracks.track_shot[t] == shot]
        joined, head_of = link_fragments(pieces, max_gap_frames=max(1, link_gap_frames))
        people = {s.track_id: s for s in joined}
        candidates = [
            s for s in joined if s.frames_observed >= min_share * shot_frames.get(shot, 1)
        ]
        ranked = rank_pairs(candidates, frame_size, num_frames=shot_frames.get(shot), config=config)
        choices.append(ShotChoice(shot, shot_frames.get(shot, 0), tuple(ranked)))
        # The best pair (pick_fighters' answer), ranked once; with no pair, its best single track.
        fighters = (
            list(ranked[0].track_ids)
            if ranked
            else pick_fighters(
                candidates, frame_size, num_frames=shot_frames.get(shot), config=config
            )
        )
        if not fighters:
            continue
        if pick is not None and tracks.track_shot[pick] == shot:
            picked = head_of[pick]
            if picked not in fighters:
                fighters = [picked, *[f for f in fighters if f != picked]][:2]
            adversary = picked
        elif colour:
            adversary = adversary_by_colour(candidates, fighters, colour)
        elif reference:
            # Found by the first shot's look; with no pick or colour that was a guess, and
            # a guess carried to the next shot stays one (the source stays 'guess').
            adversary = min(
                fighters,
                key=lambda f: colour_distance(people[f].colour, reference["adversary"]),
            )
        else:
            adversary = fighters[0]
        for piece, head in head_of.items():
            if head in fighters:
                roles[piece] = "adversary" if head == adversary else "opponent"
        if not reference:
            reference = {
                ("adversary" if f == adversary else "opponent"): people[f].colour for f in fighters
            }
    return Roles(roles, source, tuple(choices))


@dataclass(frozen=True, eq=False)
class Fighter:
    """One fighter over the whole video. Shape letters: F frames of the video, J joints."""

    role: str
    track: np.ndarray  # (F,) track id per frame, -1 where not observed
    raw_keypoints: np.ndarray  # (F, J, 2), NaN where not observed
    raw_confidence: np.ndarray  # (F, J)
    world: np.ndarray  # (F, J, 3)
    box: np.ndarray  # (F, 4)
    keypoints: np.ndarray  # (F, J, 2) refined
    confidence: np.ndarray  # (F, J) refined
    flips_fixed: int
    filled: int
    jitter_before: float
    jitter_after: float


def gather_fighter(
    tracks: VideoTracks,
    track_ids: list[int],
    role: str,
    frames: int,
    fps: float,
    config: PoseConfig,
) -> Fighter:
    """Dense per-frame arrays for the fighter made of ``track_ids``, refined over time."""
    mine = np.isin(tracks.obs_track, track_ids)
    at = tracks.obs_frame[mine]
    track = np.full(frames, -1, np.int64)
    raw = np.full((frames, JOINTS, 2), np.nan)
    conf = np.zeros((frames, JOINTS))
    world = np.full((frames, JOINTS, 3), np.nan)
    box = np.full((frames, 4), np.nan)
    track[at] = tracks.obs_track[mine]
    raw[at] = tracks.keypoints[mine]
    conf[at] = tracks.confidence[mine]
    world[at] = tracks.world[mine]
    box[at] = tracks.obs_box[mine]
    # Where the fighter is next seen in another shot: no refinement reaches across a cut.
    order = np.argsort(at)
    shot = tracks.track_shot[tracks.obs_track[mine]][order]
    refined = refine(
        raw,
        conf,
        fps,
        config.refine,
        flip_permutation(BLAZEPOSE_33),
        groups=flip_groups(BLAZEPOSE_33),
        bones=flip_bones(BLAZEPOSE_33),
        cuts=at[order][1:][np.diff(shot) != 0].tolist(),
    )
    return Fighter(
        role,
        track,
        raw,
        conf,
        world,
        box,
        refined.keypoints,
        refined.confidence,
        refined.flips_fixed,
        refined.filled,
        refined.jitter_before,
        refined.jitter_after,
    )


def appearance_swaps(tracks: VideoTracks, fighters: dict[str, Fighter]) -> int:
    """Frames where the two fighters look more like each other than like themselves: each
    fighter's observed clothing colour is nearer the other's mean colour. Counted as the number
    of times such a run starts; the stage reports it as ``identity_switches`` (there is no
    ground truth on real video, and a swap of identities shows exactly this way)."""
    if len(fighters) < 2:
        return 0
    a, b = fighters["adversary"], fighters["opponent"]
    colour_at = {}
    means = {}
    for role, fighter in (("adversary", a), ("opponent", b)):
        mine = np.isin(tracks.obs_track, np.unique(fighter.track[fighter.track >= 0]))
        colour_at[role] = dict(
            zip(tracks.obs_frame[mine].tolist(), tracks.colour[mine], strict=True)
        )
        means[role] = tracks.colour[mine].mean(axis=0)
    swapped = []
    for frame in sorted(set(colour_at["adversary"]) & set(colour_at["opponent"])):
        ca, cb = colour_at["adversary"][frame], colour_at["opponent"][frame]
        own = colour_distance(ca, means["adversary"]) + colour_distance(cb, means["opponent"])
        crossed = colour_distance(ca, means["opponent"]) + colour_distance(cb, means["adversary"])
        swapped.append(crossed < own)
    return int(sum(1 for i, s in enumerate(swapped) if s and (i == 0 or not swapped[i - 1])))


def _people_at(frame: int, fighters: dict[str, Fighter]):
    for role, f in fighters.items():
        if np.isfinite(f.keypoints[frame]).any() and np.isfinite(f.box[frame]).all():
            yield int(f.track[frame]), role, f.box[frame], f.keypoints[frame], f.confidence[frame]


def render_overlay(
    video: Path,
    fighters: dict[str, Fighter],
    *,
    fps: float,
    frames: int,
    size: tuple[int, int],
    config: PoseConfig,
    source_frames: Sequence[int] | None = None,
) -> tuple[list[MediaRow], dict[str, bytes]]:
    """The overlay MP4 of ``overlay_seconds`` from where the fighters are first seen (together
    if they ever are: the review must show the skeletons the later stages use, however late in
    the video they appear) and the PNG stills. ``source_frames``: ingest's re-timing of a
    variable-rate video.

    Returns their ``pose_media`` rows and the files they name (artifact name -> bytes).
    """
    import cv2

    media, files = [], {}

    def add(kind: str, frame: int, data: bytes, suffix: str) -> None:
        name = artifact_name(data, suffix)
        media.append(MediaRow(kind, frame, name))
        files[name] = data

    seen = np.array([np.isfinite(f.keypoints).any(axis=(1, 2)) for f in fighters.values()])
    both = np.flatnonzero(seen.all(axis=0))
    anyone = np.flatnonzero(seen.any(axis=0))
    start = int(both[0] if len(both) else anyone[0] if len(anyone) else 0)
    end = (
        frames
        if config.overlay_seconds <= 0
        else min(frames, start + round(config.overlay_seconds * fps))
    )
    out_size = overlay_size(*size, config.overlay_max_side)

    def frames_of(first: int, last: int):
        source = None if source_frames is None else source_frames[first:last]
        return read_frames(video, first, last, source)

    with scratch_dir("overlay") as tmp:
        path = Path(tmp) / "overlay.mp4"
        with H264Writer(path, out_size, fps) as writer:
            for index, frame in frames_of(start, end):
                writer.write(draw_people(frame, _people_at(index, fighters)))
        add("overlay", start, path.read_bytes(), ".mp4")
    pool = both if len(both) else np.arange(frames)
    for index in (
        sorted(set(pool[np.linspace(0, len(pool) - 1, config.stills).round().astype(int)].tolist()))
        if config.stills and len(pool)
        else []
    ):
        _, frame = next(frames_of(index, index + 1))
        drawn = draw_people(frame, _people_at(index, fighters))
        small = cv2.resize(
            drawn, overlay_size(*size, config.overlay_max_side), interpolation=cv2.INTER_AREA
        )
        ok, png = cv2.imencode(".png", small)
        add("still", index, png.tobytes(), ".png")
    return media, files


def _flat(values: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.float32).reshape(len(values), -1)


def assemble(
    video: Path,
    spans: list[ChunkSpan],
    chunks: list[ChunkTracks],
    *,
    frames: int,
    fps: float,
    size: tuple[int, int],
    shots: Mapping[int, int],
    colour: str | None,
    pick: int | None,
    config: PoseConfig,
    source_frames: Sequence[int] | None = None,
) -> StageOutput:
    """Join the chunks, choose and refine the fighters, render the overlay: rows, metrics and
    the overlay's files.

    Raises :class:`BadInput` when nobody in the video qualifies as a fighter.
    """
    start = time.perf_counter()
    tracks = merge_chunks(spans, chunks)
    roles = assign_roles(
        tracks,
        shot_frames=shots,
        frame_size=size,
        colour=colour,
        pick=pick,
        min_share=config.min_fighter_share,
        link_gap_frames=round(config.link_gap_s * fps),
        config=config.fighters,
    )
    fighters = {
        role: gather_fighter(tracks, ids, role, frames, fps, config)
        for role in ROLES
        if (ids := [t for t, r in roles.by_track.items() if r == role])
    }
    if not fighters:
        raise BadInput(STAGE, f"no fighters found in {video}")
    notes = []
    if len(fighters) == 1:
        notes.append(f"only one fighter found in {video}; the pose stage keeps that one")
    if roles.source == "guess" and len(fighters) == 2:
        notes.append(
            "no colour or pick given: the adversary is a guess; set it with `ringside pick`"
        )
    notes += roles.choice_notes(config.min_together_share, config.min_choice_margin)
    media, files = render_overlay(
        video,
        fighters,
        fps=fps,
        frames=frames,
        size=size,
        config=config,
        source_frames=source_frames,
    )
    seconds = sum(c.seconds for c in chunks) + time.perf_counter() - start

    observed = {r: f.track >= 0 for r, f in fighters.items()}
    both = (
        np.logical_and.reduce(list(observed.values()))
        if len(fighters) == 2
        else np.zeros(frames, bool)
    )
    conf_raw = np.concatenate([f.raw_confidence[observed[r]] for r, f in fighters.items()])
    metrics = {
        "frames": float(frames),
        "fighters": float(len(fighters)),
        "both_fighters_share": float(both.mean()),
        "tracks": float(len(tracks.track_shot)),
        "identity_switches": float(appearance_swaps(tracks, fighters)),
        "jitter_px": float(np.nanmean([f.jitter_after for f in fighters.values()])),
        "jitter_px_raw": float(np.nanmean([f.jitter_before for f in fighters.values()])),
        "flips_fixed": float(sum(f.flips_fixed for f in fighters.values())),
        "joints_filled": float(sum(f.filled for f in fighters.values())),
        "detections_per_frame": len(tracks.det_frame) / frames,
        "adversary_guessed": float(roles.source == "guess"),
        **roles.choice_metrics(),
        "fps": frames / max(seconds, 1e-9),
    }
    for role, fighter in fighters.items():
        metrics[f"{role}_share"] = float(observed[role].mean())
        metrics[f"{role}_tracks"] = float(len(np.unique(fighter.track[fighter.track >= 0])))
    for name, index in zip(COCO_17, BLAZEPOSE_TO_COCO17, strict=True):
        metrics[f"confidence_{name}"] = float(conf_raw[:, index].mean()) if len(conf_raw) else 0.0
    metrics = {k: v for k, v in metrics.items() if np.isfinite(v)}

    track_rows = [
        TrackRow(
            s.track_id,
            int(tracks.track_shot[s.track_id]),
            roles.by_track[s.track_id],
            s.first_frame,
            s.last_frame,
            s.frames_observed,
        )
        for s in summaries(tracks)
    ]
    keypoint_columns: dict[str, list[np.ndarray]] = {}
    for role, f in fighters.items():
        rows = np.flatnonzero(np.isfinite(f.keypoints).any(axis=(1, 2)) | observed[role])
        parts = {
            "frame": rows.astype(np.int64),
            "role": np.array([role] * len(rows)),
            "track": np.where(f.track[rows] >= 0, f.track[rows], -1),
            "x": _flat(f.keypoints[rows, :, 0]),
            "y": _flat(f.keypoints[rows, :, 1]),
            "confidence": _flat(f.confidence[rows]),
            "raw_x": _flat(f.raw_keypoints[rows, :, 0]),
            "raw_y": _flat(f.raw_keypoints[rows, :, 1]),
            "raw_confidence": _flat(f.raw_confidence[rows]),
            "world": _flat(f.world[rows]),
        }
        for name, values in parts.items():
            keypoint_columns.setdefault(name, []).append(values)
    rows = {
        "pose_detections": {
            "frame": tracks.det_frame,
            "score": tracks.det_score,
            "box": _flat(tracks.det_box),
        },
        "pose_tracks": track_rows,
        "pose_observations": {
            "frame": tracks.obs_frame,
            "track": tracks.obs_track,
            "score": tracks.obs_score,
            "box": _flat(tracks.obs_box),
        },
        "pose_keypoints": {k: np.concatenate(v) for k, v in keypoint_columns.items()},
        "pose_media": media,
    }
    return StageOutput(rows, metrics, tuple(notes), files)
