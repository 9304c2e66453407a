"""Commands that run and inspect the per-video pipeline: process, status, rerun, pick, metrics,
datasets, demo."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from flows.cli.environment import EXIT_BAD_INPUT, flow_server
from flows.cli.parser import overrides
from flows.cli.tables import print_opponent, print_summary, print_table
from flows.cli.upkeep import pull_assets
from storage.paths import DataPaths


def run_pipeline(*args, **kwargs) -> int:
    """`pipeline_summaries` as a command's exit code."""
    return EXIT_BAD_INPUT if pipeline_summaries(*args, **kwargs) is None else 0


def pipeline_summaries(
    args,
    paths: DataPaths,
    videos: list[str],
    adversary: str,
    colour,
    notes,
    rerun: list[str] | None = None,
) -> list | None:
    """The pipeline on ``videos`` as the command's ``args`` set it, its table and opponent
    printed; its stages' summaries, or None when it failed (what failed printed)."""
    from flows.config import load_config
    from flows.launch import run_parameters
    from flows.pipeline import PipelineFailed, video_to_opponent
    from storage.check import remove_stale_temporaries
    from tasks.ingest.probe import check_file

    # Cheap checks before Prefect starts, so a mistyped path fails in milliseconds.
    for video in videos:
        check_file(Path(video))
    config = load_config(args.config, overrides(args))
    # Half-written files of a process killed mid-write (`storage.files.write_atomic`).
    remove_stale_temporaries(paths.artifacts)
    parameters = run_parameters(
        paths,
        videos,
        adversary,
        colour,
        notes,
        config.as_dict(),
        until=getattr(args, "until", None),
        rerun=rerun,
    )
    try:
        with flow_server(paths):
            summaries = video_to_opponent(**parameters)
    except PipelineFailed as failed:
        if failed.summaries:
            print_summary(failed.summaries, paths, args.json)
        for line in failed.failures:
            print(f"ringside: error: {line}", file=sys.stderr)
        return None
    print_summary(summaries, paths, args.json)
    evaluated = [s for s in summaries if s.stage == "evaluate"]
    if evaluated and not args.json:
        print_opponent(paths, evaluated[-1])
    return summaries


def process_command(args, paths: DataPaths) -> int:
    from flows.config import load_config
    from flows.pipeline import stages_until
    from tasks.ingest.probe import check_duration

    # A video shorter than the dataset's shortest clip passes ingest, pose and lift and is
    # refused by the dataset a minute later: refuse it before they run.
    if "dataset" in stages_until(args.until):
        min_clip_s = load_config(args.config, overrides(args)).dataset.min_clip_s
        for video in args.videos:
            check_duration(Path(video), min_clip_s, "the dataset stage (dataset.min_clip_s)")
    return run_pipeline(args, paths, args.videos, args.adversary, args.adversary_colour, args.notes)


def status_command(args, paths: DataPaths) -> int:
    from storage.db import connect
    from storage.records import chained_states, stage_states
    from tasks.dataset.store import list_datasets
    from tasks.registry import Subject, names, per_video

    db = paths.db
    videos: list[dict[str, Any]] = []
    opponents: list[dict[str, Any]] = []
    unusable: list[dict[str, Any]] = []
    # The JSON's documented fields; the dashboard shows the timings too.
    fields = ("video_id", "stage", "key", "state", "error")
    if db.exists():
        with connect(db, read_only=True) as con:
            videos = [{f: r[f] for f in fields} for r in stage_states(con, per_video())]
            listed = list_datasets(con)
            datasets = [d["dataset_key"] for d in reversed(listed)]
            chain = names(Subject.DATASET, Subject.RUN)
            opponents = [{f: r[f] for f in fields} for r in chained_states(con, datasets, chain)]
            unusable = [d for d in listed if d["unusable"] is not None]
    if args.json:
        print(json.dumps(videos + opponents))
        return 0

    def short(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
        return [{**r, "video_id": r["video_id"][:12], "key": (r["key"] or "")[:12]} for r in rows]

    print_table(short(videos), ["video_id", "stage", "state", "key", "error"])
    if opponents:
        # Training runs on a dataset (all of an adversary's videos), evaluation on a run.
        print()
        print_table(
            [{**r, "of": r["video_id"]} for r in short(opponents)],
            ["of", "stage", "state", "key", "error"],
        )
    if unusable:
        # A dataset nobody can train on shows no training row of its own to fail: say why here.
        print()
        for d in unusable:
            print(f"dataset {d['dataset_key'][:12]} of {d['adversary']}: {verdict(d['unusable'])}")
    return 0


def rerun_command(args, paths: DataPaths) -> int:
    from storage.db import connect
    from tasks.ingest.store import ingested_video

    with connect(paths.db, read_only=True) as con:
        video = ingested_video(con, args.video)
    return run_pipeline(
        args,
        paths,
        [video.path],
        video.adversary,
        video.colour,
        video.notes,
        rerun=[args.stage],
    )


def pick_command(args, paths: DataPaths) -> int:
    from storage.db import connect
    from tasks.ingest.store import ingested_video
    from tasks.pose.store import record_pick

    with connect(paths.db) as con:
        video = ingested_video(con, args.video)
        record_pick(con, video.video_id, args.track)
    return run_pipeline(args, paths, [video.path], video.adversary, video.colour, video.notes)


def metrics_command(args, paths: DataPaths) -> int:
    from storage.db import connect
    from storage.records import latest_metrics

    db = paths.db
    rows = []
    if db.exists():
        with connect(db, read_only=True) as con:
            rows = latest_metrics(con, args.stage)
    if args.json:
        print(json.dumps(rows))
    else:
        print_table(
            [
                {
                    **r,
                    "video_id": r["video_id"][:12],
                    "key": r["key"][:12],
                    "value": f"{r['value']:.6g}",
                }
                for r in rows
            ],
            ["video_id", "stage", "name", "value", "key"],
        )
    return 0


def datasets_command(args, paths: DataPaths) -> int:
    from storage.db import connect
    from tasks.dataset.store import list_datasets

    db = paths.db
    rows = []
    if db.exists():
        with connect(db, read_only=True) as con:
            rows = list_datasets(con)
    rows = [{**r, "created_at": str(r["created_at"])} for r in rows]
    if args.json:
        print(json.dumps(rows))
    else:
        print_table(
            [{**r, "verdict": verdict(r["unusable"])} for r in rows],
            ["dataset_key", "adversary", "videos", "transitions", "created_at", "verdict"],
        )
    return 0


def verdict(unusable: str | None) -> str:
    """A dataset's verdict as `datasets` and `status` print it."""
    return "usable" if unusable is None else f"unusable: {unusable}"


def demo_command(args, paths: DataPaths) -> int:
    from flows.config import DEMO_SETTINGS, DEMO_TRACKER_SETTINGS, load_config
    from flows.stage import run_stage_flow
    from storage.assets import BOXING_CLIPS, SAMPLE_VIDEO

    pull_assets(paths)
    assets = paths.assets
    sample = [str(assets / SAMPLE_VIDEO)]
    adversary, notes = "demo adversary", "bundled two-person sample (Pose2Sim demo, camera 1)"
    args.config = None
    # The sample is two people walking: DeepMimic's punch, retargeted onto both fighters, joins
    # the motion prior's data so that the demo opponent has punches to learn.
    args.cfg__dataset__extra_clips = str(assets / BOXING_CLIPS)
    for name, value in DEMO_SETTINGS.items():
        setattr(args, "cfg__" + name.replace(".", "__"), value)
    # The footage to its dataset, then a tracker on it, so that the evaluation also plays the
    # matched opponent (the adversary's own motion through the tracker) beside MAAIP's.
    args.until = "dataset"
    ran = pipeline_summaries(args, paths, sample, adversary, None, notes)
    if ran is None:
        return EXIT_BAD_INPUT
    (dataset,) = [s.key for s in ran if s.stage == "dataset-assemble"]
    tracker = load_config(None, [*overrides(args), *DEMO_TRACKER_SETTINGS])
    with flow_server(paths):
        trained = run_stage_flow("train", paths, dataset, config=tracker.as_dict())
    print_summary([trained], paths, args.json)
    args.until = None
    return run_pipeline(args, paths, sample, adversary, None, notes)
