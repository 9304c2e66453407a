"""Commands on training runs and the opponent: train, curves, export, evaluate, export-motion,
spar."""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

from flows.cli.environment import flow_server
from flows.cli.parser import overrides
from flows.cli.tables import classifier_lines, pivot, print_summary, print_table
from storage.paths import DataPaths


def train_command(args, paths: DataPaths) -> int:
    from flows.config import load_config
    from flows.stage import run_stage_flow
    from storage.db import connect
    from tasks.train.task import distilled_tracker, resolve_dataset

    config = load_config(args.config, overrides(args))
    info = resolve_dataset(paths.db, args.dataset)
    with connect(paths.db, read_only=True) as con:
        distilled_tracker(con, info.dataset_key, config.train)  # fail fast, before Prefect
    with flow_server(paths):
        summary = run_stage_flow(
            "train", paths, args.dataset, config=config.as_dict(), force=args.rerun
        )
    print_summary([summary], paths, args.json)
    return 0


def curves_command(args, paths: DataPaths) -> int:
    from storage.db import connect
    from tasks.train.store import CURVES, learning_curves

    if args.every < 1:
        raise ValueError(f"--every must be at least 1, got {args.every}")
    with connect(paths.db, read_only=True) as con:
        rows = learning_curves(con, args.run, every=args.every)
    if args.json:
        print(json.dumps(rows))
    else:
        shown = [{k: v if isinstance(v, str) else f"{v:.3g}" for k, v in r.items()} for r in rows]
        for r in shown:
            for name in CURVES:
                r.setdefault(name, "")
        print_table(shown, ["iterations", *CURVES])
    return 0


def export_command(args, paths: DataPaths) -> int:
    from tasks.errors import BadInput
    from tasks.opponent.export import (
        deepmimic_clip,
        matched_footage,
        replayed_footage,
        trained_policy,
    )
    from tasks.opponent.tracker import KIND as TRACKER

    trained = trained_policy(paths.db, paths.artifacts, args.run)
    agent = 0 if args.agent == "adversary" else 1
    clip = footage = None
    if args.matched:
        if trained.kind != TRACKER or args.clip is not None:
            raise BadInput("--matched", "takes a tracker run ('track') and no --clip")
        motion = replayed_footage if args.matched_motion == "replay" else matched_footage
        footage = motion(paths.db, trained, agent)
    elif trained.kind == TRACKER:
        if args.clip is None:
            raise BadInput(
                f"--run {args.run}",
                "is a 'track' run (train.objective), which follows clips: export it with the "
                "clip it plays (--clip NAME, one of DeepMimic's), or as the matched opponent "
                "playing its footage (--matched)",
            )
        qpos = deepmimic_clip(
            paths.assets, args.clip, trained.bones[agent], fps=trained.config.env.policy_hz
        )
        clip = (args.clip, qpos)
    elif args.clip is not None:
        raise BadInput(f"--clip {args.clip}", "only a tracker run plays a clip; this is MAAIP's")
    out = args.out or paths.root / "opponents" / f"{trained.run_key[:12]}-{args.agent}"
    folder = trained.export(agent, out, clip, footage)
    if args.json:
        print(
            json.dumps(
                {"folder": str(folder), **json.loads((folder / "manifest.json").read_text())}
            )
        )
    else:
        print(
            f"{args.agent} of run {trained.run_key[:12]} (iteration {trained.iteration}): {folder}"
        )
    return 0


def evaluate_command(args, paths: DataPaths) -> int:
    from flows.config import load_config
    from flows.stage import run_stage_flow
    from storage.db import connect
    from storage.records import output_metrics
    from tasks.evaluate.stage import POLICIES
    from tasks.evaluate.store import evaluation_tables
    from tasks.evaluate.task import resolve_training_run

    config = load_config(args.config, overrides(args))
    db = paths.db
    resolve_training_run(db, args.run)  # fail fast, before Prefect starts

    with flow_server(paths):
        summary = run_stage_flow(
            "evaluate", paths, args.run, config=config.as_dict(), force=args.rerun
        )
    with connect(db, read_only=True) as con:
        tables = evaluation_tables(con, summary.key, summary.video_id)
        metrics = output_metrics(con, "evaluate", summary.video_id, summary.key)
    if args.json:
        print(
            json.dumps(
                {"summary": dataclasses.asdict(summary), "metrics": metrics, "tables": tables}
            )
        )
        return 0
    print_summary([summary], paths, False)

    def number(value) -> str:
        return "" if value is None else f"{value:.4g}"

    print("\ndamage per episode, N (MAAIP Table 1)")
    print_table(
        [
            {
                **r,
                "run_key": r["run_key"][:12],
                "received_n": number(r["received_n"]),
                "dealt_n": number(r["dealt_n"]),
            }
            for r in tables["damage"]
        ],
        ["run_key", "control_task", "agent", "received_n", "dealt_n", "episodes", "frames"],
    )
    if tables["heading"]:
        print("\nnormalised heading return (MAAIP Table 2)")
        print_table(
            [
                {
                    **r,
                    "run_key": r["run_key"][:12],
                    "normalized_return": number(r["normalized_return"]),
                }
                for r in tables["heading"]
            ],
            ["run_key", "motion_prior", "agent", "normalized_return", "episodes", "frames"],
        )
    # Only the fighters evaluated: the matched pair is there only where the dataset has a
    # tracker that finished some of its train footage.
    evaluated = {r["policy"] for r in tables["style"]}
    policies = [p for p in POLICIES if p in evaluated]
    print("\nstyle: simulated value (distance to the adversary's real one, 0-1)")
    style = pivot(
        tables["style"],
        "statistic",
        "policy",
        lambda r: f"{number(r['simulated'])} ({r['distance']:.2f})",
    )
    real = {r["statistic"]: number(r["real"]) for r in tables["style"]}
    print_table(
        [{**r, "real": real[r["statistic"]]} for r in style], ["statistic", "real", *policies]
    )
    names = {p: "style_score" + ("" if p == "adversary" else f"_{p}") for p in policies}
    scores = ", ".join(f"{p} {number(metrics.get(names[p]))}" for p in policies)
    print(f"style_score (lower is closer): {scores}")
    print()
    for line in classifier_lines(tables["classifier"], metrics):
        print(line)
    print(
        "\nboxing (MSc thesis §6.1); footage: the held-out footage's, its 95 % interval _low-_high"
    )
    boxing = pivot(tables["boxing"], "metric", "policy", lambda r: number(r["value"]))
    shown = [*policies, "footage"]
    print_table([{p: "" for p in shown} | r for r in boxing], ["metric", *shown])
    print("\nartifacts")
    print_table(tables["artifacts"], ["name", "artifact"])
    return 0


def export_motion_command(args, paths: DataPaths) -> int:
    from storage.artifacts import read_bytes
    from storage.db import connect
    from tasks.errors import BadInput
    from tasks.evaluate.motion_files import BOUTS, bout_files, lifted_files
    from tasks.evaluate.store import evaluation_artifacts, newest_evaluation, resolve_run
    from tasks.ingest.store import ingested_video, load_ingest
    from tasks.lift.store import load_motion, newest_lift
    from tasks.opponent.export import write_folder

    if not paths.db.exists():
        raise BadInput(str(paths.db), "no database yet: process a video first")
    with connect(paths.db, read_only=True) as con:
        if args.video is not None:
            video_id = ingested_video(con, args.video).video_id
            found = newest_lift(con, video_id)
            if found is None:
                raise BadInput(f"--video {args.video}", "has no lift output yet: process it")
            ingest = load_ingest(con, video_id, found[1])
            files = lifted_files(load_motion(con, video_id, found[0]), ingest.shots, ingest.fps)
            what, default = f"lifted motion of video {video_id[:12]}", video_id[:12]
        else:
            run = resolve_run(con, args.run)
            key = newest_evaluation(con, run.run_key)
            stored = {} if key is None else evaluation_artifacts(con, key, run.run_key)
            if BOUTS not in stored:
                raise BadInput(
                    f"--run {args.run}",
                    "has no evaluation that stored its bouts: run "
                    f"`ringside evaluate --run {run.run_key[:12]}`",
                )
            files = bout_files(read_bytes(paths.artifacts, stored[BOUTS]))
            what, default = f"bouts of run {run.run_key[:12]}", f"{run.run_key[:12]}-bouts"
    if not files:
        raise BadInput(what, "holds no motion to export")
    folder = write_folder(
        args.out or paths.root / "motion" / default,
        {name: file.text.encode() for name, file in files.items()},
    )
    frames = {name: file.frames for name, file in files.items()}
    if args.json:
        print(json.dumps({"folder": str(folder), "files": frames}))
    else:
        print(
            f"{what}: {len(files)} BVH files, {sum(frames.values())} frames at 30 Hz, in {folder}"
        )
    return 0


def spar_command(args, _paths: DataPaths) -> int:
    from tqdm import tqdm

    from tasks.opponent.folder import load_opponent
    from tasks.opponent.spar import STILL, partner_name, spar

    opponent = load_opponent(args.opponent)
    partner = None if args.partner == STILL else load_opponent(Path(args.partner))
    with tqdm(
        total=round(args.seconds),
        unit="s",
        desc="spar",
        disable=args.json or not sys.stderr.isatty(),
        bar_format="{l_bar}{bar}| {n:.0f}/{total} simulated s [{elapsed}<{remaining}]",
    ) as bar:
        result = spar(
            opponent,
            partner,
            seconds=args.seconds,
            video=args.video,
            pace=args.pace,
            progress=lambda t: bar.update(t - bar.n),
        )
    if args.json:
        print(json.dumps(result.as_dict()))
    else:
        spent = result.timings_s
        total = sum(spent.values()) or 1.0
        print(
            f"{result.simulated_s:.0f} simulated s against {partner_name(partner)} in "
            f"{result.wall_s:.1f} s"
            f"; falls: opponent {result.falls[0]}, partner {result.falls[1]}; damage received: "
            f"opponent {result.damage_received_n[0]:.0f} N, partner "
            f"{result.damage_received_n[1]:.0f} N"
        )
        print("time: " + ", ".join(f"{k} {v / total:.0%}" for k, v in spent.items()))
        if result.video:
            print(f"video: {result.video} ({result.frames_rendered} frames)")
    print(f"realtime_factor: {result.realtime_factor:.1f} x")
    return 0
