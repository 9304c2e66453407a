"""The ingest stage: a video file becomes a registered video with its probe, shots and chunks."""

from __future__ import annotations

import time
from pathlib import Path

from storage.artifacts import artifact_name
from storage.keys import code_version
from tasks.ingest.config import AdversaryDeclaration, IngestConfig
from tasks.ingest.probe import VideoFile, plan_chunks, scan_video
from tasks.ingest.store import AdversaryRow, ChunkRow, ProbeRow, ShotRow
from tasks.runner import StageOutput, StageSpec

STAGE = "ingest"


def ingest_code() -> str:
    return code_version("tasks.ingest")


def ingest_spec(
    config: IngestConfig, video_id: str, declaration: AdversaryDeclaration
) -> StageSpec:
    return StageSpec(
        STAGE, video_id, config, ingest_code(), {"video": video_id, "adversary": declaration}
    )


def ingest_video(
    video: VideoFile, declaration: AdversaryDeclaration, config: IngestConfig
) -> StageOutput:
    """Scan ``video``: the rows, metrics and files (the shots' thumbnails) of its ingest output."""
    start = time.perf_counter()
    scan = scan_video(Path(video.path), config)
    seconds = time.perf_counter() - start
    p = scan.probe
    thumbnails = [artifact_name(s.thumbnail, ".png") for s in scan.shots]
    shots = [
        ShotRow(s.index, s.start, s.end, s.cut_distance, name)
        for s, name in zip(scan.shots, thumbnails, strict=True)
    ]
    chunks = [
        ChunkRow(c.index, c.shot, c.start, c.end)
        for c in plan_chunks(scan.shots, config.chunk_frames)
    ]
    rows = {
        "ingest_probes": [
            ProbeRow(
                video.path,
                p.fps,
                p.frames,
                p.frames_declared,
                p.width,
                p.height,
                p.codec,
                p.duration_s,
                None if p.source_frames is None else p.source_frames.tolist(),
            )
        ],
        "ingest_adversaries": [
            AdversaryRow(declaration.name, declaration.colour, declaration.notes)
        ],
        "ingest_shots": shots,
        "ingest_chunks": chunks,
    }
    metrics = {
        "frames": float(p.frames),
        "fps": p.fps,
        "duration_s": p.duration_s,
        "width": float(p.width),
        "height": float(p.height),
        "shot_cuts": float(len(scan.shots) - 1),
        "chunks": float(len(chunks)),
        "size_mb": video.size_bytes / 1e6,
        "decode_fps": p.frames_decoded / max(seconds, 1e-9),
        "frames_decoded": float(p.frames_decoded),
        "variable_frame_rate": float(p.source_frames is not None),
    }
    notes = ()
    if p.source_frames is not None:
        slowest, fastest = p.fps_range
        repeated = int(p.frames - len(set(p.source_frames.tolist())))
        notes = (
            f"variable frame rate ({slowest:.3g} to {fastest:.3g} fps): re-timed by the "
            f"container's timestamps to {p.fps:.4g} fps, {p.frames_decoded} decoded frames on "
            f"{p.frames} grid frames ({repeated} show the frame before again)",
        )
    files = {name: s.thumbnail for name, s in zip(thumbnails, scan.shots, strict=True)}
    return StageOutput(rows, metrics, notes, files)
