"""The ``ringside`` command: process, status, rerun, metrics, assets, dashboard, serve, demo.

Prefect reads its settings when it is first imported, so ``main`` points Prefect at the data
directory before anything imports it.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import dataclasses
import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

EXIT_FAILED = 1
EXIT_BAD_INPUT = 2


def prepare_environment(data_root: Path, *, verbose: bool) -> None:
    """Prefect settings Ringside needs, unless the user has set them: its home (ephemeral
    server database, cached results) inside the data directory, no telemetry, a quiet console."""
    os.environ["RINGSIDE_DATA"] = str(data_root)
    os.environ.setdefault("PREFECT_HOME", str(data_root / "prefect"))
    # Prefect creates its home with a plain mkdir and cannot start its server without it.
    Path(os.environ["PREFECT_HOME"]).expanduser().mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120")
    # FFmpeg's own complaints ("moov atom not found") would bury our one-line errors.
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    # MuJoCo picks its offscreen GL backend when first imported: EGL renders without a screen
    # (Mesa's software EGL on a machine without a GPU).
    os.environ.setdefault("MUJOCO_GL", "egl")
    # Torch's OpenMP threads spin while they wait; when another process shares the cores, the
    # training updates on 2 threads ran 2-15x slower than on 1 (measured during a long run).
    # Passive waiting keeps 2 threads at least as fast as 1 on a shared machine.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    if not verbose:
        # Flow and task logs still reach the Prefect API and UI; the terminal shows our summary.
        os.environ.setdefault("PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL", "CRITICAL")
    if "PREFECT_API_URL" not in os.environ:
        from flows.serve import served_api

        # While `ringside serve` runs on this data directory, every run reports to its server
        # and shows in its UI; otherwise a flow command starts a server of its own
        # (`_flow_server`).
        api = served_api(data_root)
        if api is not None:
            os.environ["PREFECT_API_URL"] = api


@contextlib.contextmanager
def _flow_server(data_root: Path):
    """Where a command's flows report: `ringside serve`'s server or the user's
    (PREFECT_API_URL), else a private server started here, once the command has checked its
    input (it takes seconds to start: a mistyped path waited for it). Then the runs a killed
    command left RUNNING are marked crashed."""
    if "PREFECT_API_URL" not in os.environ:
        from flows.serve import private_server

        # Not Prefect's temporary server: a killed command would leave that one running.
        os.environ["PREFECT_API_URL"] = private_server(data_root)
    with _prefect_settings_of_this_command():
        _crash_stale_flow_runs(data_root)
        yield


def _config_flags(parser: argparse.ArgumentParser) -> None:
    from flows.config import SECTIONS
    from tasks.config import leaf_fields

    parser.add_argument("--config", type=Path, help="TOML config (default: ./ringside.toml)")
    for section, cls in SECTIONS.items():
        group = parser.add_argument_group(f"{section} settings (override {section} in the config)")
        for path, f in leaf_fields(cls, (section,)):
            group.add_argument(
                "--" + "-".join(path).replace("_", "-"),
                dest="cfg__" + "__".join(path),
                metavar="VALUE",
                help=f"{f.metadata['help']} (default {f.default})".replace("%", "%%"),
            )


def _overrides(args: argparse.Namespace) -> list[str]:
    return [
        f"{'.'.join(name.split('__')[1:])}={value}"
        for name, value in vars(args).items()
        if name.startswith("cfg__") and value is not None
    ]


def build_parser() -> argparse.ArgumentParser:
    from flows.config import PIPELINE_STAGES

    parser = argparse.ArgumentParser(
        prog="ringside",
        description="Turn an adversary's fight footage into a sparring opponent.",
    )
    parser.add_argument(
        "--data", type=Path, help="data directory (default: $RINGSIDE_DATA or ./data)"
    )
    parser.add_argument("--verbose", action="store_true", help="show Prefect's logs too")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    process = commands.add_parser("process", help="run the pipeline on videos now")
    process.add_argument("videos", nargs="+", metavar="VIDEO")
    process.add_argument("--adversary", required=True, metavar="NAME", help="who the adversary is")
    process.add_argument("--adversary-colour", metavar="COLOUR", help="trunk colour or #rrggbb")
    process.add_argument("--notes", help="free text kept with the video")
    process.add_argument("--until", choices=PIPELINE_STAGES, help="stop after this stage")
    process.add_argument("--json", action="store_true", help="print the summary as JSON")
    _config_flags(process)

    status = commands.add_parser("status", help="what is cached, done or failed, per video")
    status.add_argument("--json", action="store_true")

    rerun = commands.add_parser(
        "rerun", help="recompute one stage of one video (and what depends on it), cache or not"
    )
    rerun.add_argument("stage", choices=PIPELINE_STAGES)
    rerun.add_argument("--video", required=True, metavar="ID", help="video id (a prefix will do)")
    rerun.add_argument("--until", choices=PIPELINE_STAGES, help="stop after this stage")
    rerun.add_argument("--json", action="store_true")
    _config_flags(rerun)

    pick = commands.add_parser(
        "pick", help="say which track is the adversary in a video, then rerun what depends on it"
    )
    pick.add_argument("--video", required=True, metavar="ID", help="video id (a prefix will do)")
    pick.add_argument(
        "--track",
        required=True,
        type=int,
        metavar="N",
        help="track id, as `ringside status` and the pose overlay show it",
    )
    pick.add_argument("--until", choices=PIPELINE_STAGES, help="stop after this stage")
    pick.add_argument("--json", action="store_true")
    _config_flags(pick)

    train = commands.add_parser(
        "train", help="train the fighters' policies on a dataset (MAAIP; resumes if killed)"
    )
    train.add_argument("--dataset", required=True, metavar="KEY", help="see `ringside datasets`")
    train.add_argument("--rerun", action="store_true", help="train again from scratch")
    train.add_argument("--json", action="store_true")
    _config_flags(train)

    curves = commands.add_parser(
        "curves", help="a training run's learning curves, averaged over blocks of iterations"
    )
    curves.add_argument(
        "--run", required=True, metavar="KEY", help="training key (a prefix will do)"
    )
    curves.add_argument("--every", type=int, default=100, metavar="N", help="iterations per row")
    curves.add_argument("--json", action="store_true")

    export = commands.add_parser(
        "export", help="write a trained fighter as an opponent folder (ONNX policy + humanoid)"
    )
    export.add_argument(
        "--run", required=True, metavar="KEY", help="training key (a prefix will do)"
    )
    export.add_argument(
        "--agent",
        choices=["adversary", "opponent"],
        default="adversary",
        help="which of the run's two fighters (default: the adversary)",
    )
    export.add_argument(
        "--out", type=Path, help="folder to write (default: DATA/opponents/<run>-<agent>)"
    )
    export.add_argument("--json", action="store_true")

    motion = commands.add_parser(
        "export-motion",
        help="write motion as BVH for animation tools: a video's lifted fighters, or the bouts "
        "of an evaluated run",
        description="BVH files at 30 Hz, y up, centimetres, each fighter on its own humanoid's "
        "skeleton (import into Blender with scale 0.01 for metres). --video: each fighter's "
        "cleaned lifted motion, a file per shot (and per unbroken stretch of it); --run: each "
        "episode of the run's newest evaluation, a file per fighter.",
    )
    source = motion.add_mutually_exclusive_group(required=True)
    source.add_argument("--video", metavar="ID", help="a processed video (a prefix will do)")
    source.add_argument("--run", metavar="KEY", help="an evaluated training run (a prefix will do)")
    motion.add_argument(
        "--out", type=Path, help="folder to write (default: DATA/motion/<video> or <run>-bouts)"
    )
    motion.add_argument("--json", action="store_true")

    spar = commands.add_parser(
        "spar", help="run an exported opponent against a partner in MuJoCo (onnxruntime only)"
    )
    spar.add_argument("opponent", type=Path, help="an opponent folder (`ringside export`)")
    spar.add_argument(
        "--partner",
        default="still",
        metavar="FOLDER|still",
        help="another opponent folder, or 'still' (a boxer holding its guard; default)",
    )
    spar.add_argument("--seconds", type=float, default=60.0, help="simulated seconds (60)")
    spar.add_argument("--video", type=Path, help="render the bout to this MP4 (H.264)")
    spar.add_argument("--pace", action="store_true", help="no faster than real time")
    spar.add_argument("--json", action="store_true")

    evaluate = commands.add_parser(
        "evaluate",
        help="judge a training run: damage, style and boxing tables, ONNX export, a rendered bout",
    )
    evaluate.add_argument(
        "--run", required=True, metavar="KEY", help="training key (a prefix will do)"
    )
    evaluate.add_argument("--rerun", action="store_true", help="evaluate again, cached or not")
    evaluate.add_argument("--json", action="store_true")
    _config_flags(evaluate)

    metrics = commands.add_parser("metrics", help="each stage's metrics per video or dataset")
    metrics.add_argument("--stage", choices=PIPELINE_STAGES)
    metrics.add_argument("--json", action="store_true")

    check = commands.add_parser(
        "check",
        help="read every table and artifact back; say what is damaged (--repair: recompute it)",
        description="Reads every row of every table (DuckDB checks its blocks only when they "
        "are read) and hashes every file the database names, then prints per stage and video "
        "what is damaged; exit code 1 when something is. --repair copies every row that reads "
        "back into a new database file, leaving out the damaged outputs so that the next "
        "`ringside process` (or `rerun`) computes them again, keeps the damaged file beside it "
        "and deletes temporary files of interrupted writes.",
    )
    check.add_argument("--repair", action="store_true", help="repair what a rerun can give back")
    check.add_argument("--json", action="store_true")

    backup = commands.add_parser(
        "backup",
        help="a consistent copy of the database in a folder (taken under its write lock)",
    )
    backup.add_argument("folder", type=Path, help="where to write it (a backup there is replaced)")
    restore = commands.add_parser(
        "restore",
        help="put a backup in place of the database (the current file is kept beside it)",
    )
    restore.add_argument("folder", type=Path, help="a folder `ringside backup` wrote")

    datasets = commands.add_parser(
        "datasets", help="assembled training datasets: key, adversary, videos, transitions"
    )
    datasets.add_argument("--json", action="store_true")

    assets = commands.add_parser("assets", help="third-party weights and sample videos")
    assets_commands = assets.add_subparsers(dest="assets_command", required=True, metavar="ACTION")
    pull = assets_commands.add_parser("pull", help="fetch them from the package index (idempotent)")
    pull.add_argument(
        "--dev",
        action="store_true",
        help="also the test-only motion clips (DeepMimic, from pybullet's wheel)",
    )

    commands.add_parser("config", help="print every setting at its default, documented (TOML)")

    calibrate = commands.add_parser(
        "calibrate", help="camera intrinsics from photos of a chessboard, saved as JSON"
    )
    calibrate.add_argument("images", nargs="+", type=Path, metavar="IMAGE")
    calibrate.add_argument(
        "--board",
        required=True,
        metavar="COLSxROWS",
        help="inner corners of the chessboard, e.g. 9x6",
    )
    calibrate.add_argument(
        "--square", required=True, type=float, metavar="M", help="side of one square in metres"
    )
    calibrate.add_argument("-o", "--output", required=True, type=Path, metavar="FILE")

    dashboard = commands.add_parser(
        "dashboard", help="serve the analysts' dashboard (Streamlit) on this data directory"
    )
    dashboard.add_argument("--port", type=int, default=8501, metavar="N", help="default 8501")
    dashboard.add_argument(
        "--host",
        default="127.0.0.1",
        metavar="ADDRESS",
        help="address to listen on (default 127.0.0.1; 0.0.0.0 serves other machines too)",
    )
    dashboard.add_argument(
        "--no-browser", action="store_true", help="do not open the dashboard in a browser"
    )

    serve = commands.add_parser(
        "serve",
        help="start Prefect's server and UI, serve the pipeline, optionally watch a folder",
    )
    serve.add_argument(
        "--watch", type=Path, metavar="DIR", help="process new videos dropped into DIR"
    )
    serve.add_argument("--adversary", metavar="NAME", help="who the videos in DIR show")
    serve.add_argument("--adversary-colour", metavar="COLOUR", help="trunk colour or #rrggbb")
    when = serve.add_mutually_exclusive_group()
    when.add_argument("--cron", metavar="EXPR", help="when to look in DIR (default '*/5 * * * *')")
    when.add_argument(
        "--every", type=float, metavar="SECONDS", help="look in DIR every SECONDS instead"
    )
    serve.add_argument(
        "--until", choices=PIPELINE_STAGES, help="stop after this stage for videos found in DIR"
    )
    serve.add_argument(
        "--port", type=int, default=4200, metavar="N", help="the server's port (default 4200)"
    )
    serve.add_argument(
        "--workers",
        type=int,
        default=0,
        metavar="N",
        help="run the pipeline's runs on N process workers of the work pool 'ringside', N at "
        "a time (default 0: one at a time in this process's runner)",
    )
    _config_flags(serve)

    worker = commands.add_parser(
        "worker",
        help="take the pipeline's runs from the work pool of a `ringside serve --workers N`",
    )
    worker.add_argument(
        "--limit", type=int, default=1, metavar="N", help="runs at a time (default 1)"
    )

    schedule = commands.add_parser(
        "schedule", help="run the pipeline on videos later, through `ringside serve`"
    )
    schedule.add_argument("videos", nargs="+", metavar="VIDEO")
    schedule.add_argument("--adversary", required=True, metavar="NAME", help="who the adversary is")
    schedule.add_argument("--adversary-colour", metavar="COLOUR", help="trunk colour or #rrggbb")
    schedule.add_argument("--notes", help="free text kept with the video")
    schedule.add_argument(
        "--at",
        default="now",
        metavar="TIME",
        help="'now' (default), HH:MM (the next one, local time) or ISO 8601 (2030-06-01T18:30)",
    )
    schedule.add_argument("--until", choices=PIPELINE_STAGES, help="stop after this stage")
    schedule.add_argument("--json", action="store_true")
    _config_flags(schedule)

    demo = commands.add_parser(
        "demo", help="pull the assets and turn the bundled sample into an opponent"
    )
    demo.add_argument("--json", action="store_true")
    return parser


def _print_table(rows: list[dict[str, Any]], columns: list[str]) -> None:
    if not rows:
        print("(nothing yet)")
        return
    text = [[("" if r[c] is None else str(r[c])) for c in columns] for r in rows]
    widths = [max(len(c), *(len(t[i]) for t in text)) for i, c in enumerate(columns)]
    print("  ".join(c.ljust(w) for c, w in zip(columns, widths, strict=True)))
    for t in text:
        print("  ".join(v.ljust(w) for v, w in zip(t, widths, strict=True)))


def _print_summary(summaries: list, data_root: Path, as_json: bool) -> None:
    from storage.paths import data_paths

    rows = [dataclasses.asdict(s) for s in summaries]
    if as_json:
        print(json.dumps(rows))
        return
    shown = [
        {
            **r,
            "video_id": r["video_id"][:12],
            "key": r["key"][:12],
            "seconds": f"{r['seconds']:.2f}",
        }
        for r in rows
    ]
    _print_table(shown, ["video_id", "stage", "state", "key", "seconds", "path"])
    for row in rows:
        where = " ".join(filter(None, (row["stage"], row["video_id"][:12])))
        for note in row["notes"]:
            print(f"note: {where}: {note}")
    paths = data_paths(data_root)
    print(f"\nresults: {paths.db}\nartifacts: {paths.artifacts}")
    print("see them with: ringside status | ringside metrics")


def _crash_stale_flow_runs(data_root: Path) -> None:
    """Tidy Prefect before a run: a killed command's flow runs would read RUNNING for ever. A
    failure here must not stop the run, so it is only logged."""
    from flows.runs import crash_stale_flow_runs

    try:
        marked = crash_stale_flow_runs(str(data_root))
    except Exception as error:  # the API unreachable, a changed Prefect: the run goes on
        logging.getLogger("ringside").debug("stale flow runs not marked: %s", error)
        return
    if marked:
        logging.getLogger("ringside").info("marked %d stale flow runs as crashed", marked)


def _process(
    args,
    data_root: Path,
    videos: list[str],
    adversary: str,
    colour,
    notes,
    rerun: list[str] | None = None,
) -> int:
    from flows.config import load_config
    from flows.pipeline import PipelineFailed, video_to_opponent
    from flows.serve import run_parameters
    from storage.check import remove_stale_temporaries
    from storage.paths import data_paths
    from tasks.ingest.probe import check_file

    # Cheap checks before Prefect starts, so a mistyped path fails in milliseconds.
    for video in videos:
        check_file(Path(video))
    config = load_config(args.config, _overrides(args))
    # Half-written files of a process killed mid-write (`storage.files.write_atomic`).
    remove_stale_temporaries(data_paths(data_root).artifacts)
    parameters = run_parameters(
        data_root,
        videos,
        adversary,
        colour,
        notes,
        config.as_dict(),
        until=getattr(args, "until", None),
        rerun=rerun,
    )
    try:
        with _flow_server(data_root):
            summaries = video_to_opponent(**parameters)
    except PipelineFailed as failed:
        if failed.summaries:
            _print_summary(failed.summaries, data_root, args.json)
        for line in failed.failures:
            print(f"ringside: error: {line}", file=sys.stderr)
        return EXIT_BAD_INPUT
    _print_summary(summaries, data_root, args.json)
    evaluated = [s for s in summaries if s.stage == "evaluate"]
    if evaluated and not args.json:
        _print_opponent(data_root, evaluated[-1])
    return 0


def _print_opponent(data_root: Path, evaluated) -> None:
    """Where the pipeline's opponent is (the folder its evaluation exported, written where
    `ringside export` writes it), its bout and its headline numbers against the evaluation's
    baselines."""
    from storage.artifacts import artifact_path
    from storage.db import connect
    from storage.paths import data_paths
    from storage.records import output_metrics
    from tasks.evaluate.export import stored_opponent
    from tasks.evaluate.opponent import MANIFEST
    from tasks.evaluate.store import evaluation_artifacts

    paths = data_paths(data_root)
    run_key = evaluated.video_id
    with connect(paths.db, read_only=True) as con:
        metrics = output_metrics(con, "evaluate", run_key, evaluated.key)
        media = evaluation_artifacts(con, evaluated.key, run_key)
    out = data_root / "opponents" / f"{run_key[:12]}-adversary"
    folder = stored_opponent(paths.artifacts, media, out)
    iteration = json.loads((folder / MANIFEST).read_text())["iteration"]

    def number(name: str) -> str:
        value = metrics.get(name)
        return "n/a" if value is None else f"{value:.3g}"

    print(f"\nopponent of {evaluated.path}: run {run_key[:12]} at iteration {iteration}")
    print(f"  folder: {folder}   (spar with it: ringside spar {folder})")
    if "bout.mp4" in media:
        print(f"  bout:   {artifact_path(paths.artifacts, media['bout.mp4'])}")
    print(
        f"  bouts ended by a fall, per simulated minute: {number('falls_per_min')} "
        f"(untrained {number('falls_per_min_untrained')}, "
        f"standing still in its guard {number('falls_per_min_still')})"
    )
    print(
        f"  style score, 0 = the footage's statistics, lower is closer: {number('style_score')} "
        f"(untrained {number('style_score_untrained')}, standing still "
        f"{number('style_score_still')})"
    )
    print(f"  motion as BVH: ringside export-motion --run {run_key[:12]}")
    print(f"  all of it: ringside evaluate --run {run_key[:12]}   or   ringside dashboard")


def _status(args, data_root: Path) -> int:
    from flows.config import STAGES
    from storage.db import connect
    from storage.paths import data_paths
    from storage.records import opponent_states, stage_states
    from tasks.dataset.store import list_datasets

    db = data_paths(data_root).db
    videos: list[dict[str, Any]] = []
    opponents: list[dict[str, Any]] = []
    # The JSON's documented fields; the dashboard shows the timings too.
    fields = ("video_id", "stage", "key", "state", "error")
    if db.exists():
        with connect(db, read_only=True) as con:
            videos = [{f: r[f] for f in fields} for r in stage_states(con, STAGES)]
            datasets = [d["dataset_key"] for d in reversed(list_datasets(con))]
            opponents = [{f: r[f] for f in fields} for r in opponent_states(con, datasets)]
    if args.json:
        print(json.dumps(videos + opponents))
        return 0

    def short(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
        return [{**r, "video_id": r["video_id"][:12], "key": (r["key"] or "")[:12]} for r in rows]

    _print_table(short(videos), ["video_id", "stage", "state", "key", "error"])
    if opponents:
        # Training runs on a dataset (all of an adversary's videos), evaluation on a run.
        print()
        _print_table(
            [{**r, "of": r["video_id"]} for r in short(opponents)],
            ["of", "stage", "state", "key", "error"],
        )
    return 0


def _rerun(args, data_root: Path) -> int:
    from flows.videos import ingested_video

    video = ingested_video(data_root, args.video)
    return _process(
        args,
        data_root,
        [video.path],
        video.adversary,
        video.colour,
        video.notes,
        rerun=[args.stage],
    )


def _pick(args, data_root: Path) -> int:
    from flows.videos import ingested_video
    from storage.db import connect
    from storage.paths import data_paths
    from tasks.pose.store import record_pick

    video = ingested_video(data_root, args.video)
    with connect(data_paths(data_root).db) as con:
        record_pick(con, video.video_id, args.track)
    return _process(args, data_root, [video.path], video.adversary, video.colour, video.notes)


def _metrics(args, data_root: Path) -> int:
    from storage.db import connect
    from storage.paths import data_paths
    from storage.records import latest_metrics

    db = data_paths(data_root).db
    rows = []
    if db.exists():
        with connect(db, read_only=True) as con:
            rows = latest_metrics(con, args.stage)
    if args.json:
        print(json.dumps(rows))
    else:
        _print_table(
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


def _train(args, data_root: Path) -> int:
    from flows.config import load_config
    from flows.train import resolve_dataset, train_flow

    config = load_config(args.config, _overrides(args))
    resolve_dataset(data_root, args.dataset)  # fail fast, before Prefect starts
    with _flow_server(data_root):
        summary = train_flow(str(data_root), args.dataset, config.as_dict(), args.rerun)
    _print_summary([summary], data_root, args.json)
    return 0


def _curves(args, data_root: Path) -> int:
    from storage.db import connect
    from storage.paths import data_paths
    from tasks.train.store import CURVES, learning_curves

    if args.every < 1:
        raise ValueError(f"--every must be at least 1, got {args.every}")
    with connect(data_paths(data_root).db, read_only=True) as con:
        rows = learning_curves(con, args.run, every=args.every)
    if args.json:
        print(json.dumps(rows))
    else:
        shown = [{k: v if isinstance(v, str) else f"{v:.3g}" for k, v in r.items()} for r in rows]
        for r in shown:
            for name in CURVES:
                r.setdefault(name, "")
        _print_table(shown, ["iterations", *CURVES])
    return 0


def _export(args, data_root: Path) -> int:
    from storage.paths import data_paths
    from tasks.evaluate.export import trained_policy

    paths = data_paths(data_root)
    trained = trained_policy(paths.db, paths.artifacts, args.run)
    out = args.out or data_root / "opponents" / f"{trained.run_key[:12]}-{args.agent}"
    folder = trained.export(0 if args.agent == "adversary" else 1, out)
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


def _check(args, data_root: Path) -> int:
    import duckdb
    from tqdm import tqdm

    from flows.serve import prefect_database
    from storage.check import repair, scan
    from storage.db import error_line
    from storage.paths import data_paths

    paths = data_paths(data_root)
    prefect_db = prefect_database()
    with tqdm(desc="check", unit=" tables", disable=args.json or not sys.stderr.isatty()) as bar:
        problems = scan(paths.db, paths.artifacts, lambda _: bar.update(1), prefect_db)
    done = []
    if args.repair and problems:
        try:
            done = repair(paths.db, paths.artifacts, problems, prefect_db)
        except duckdb.Error as error:
            done = [f"failed: {error_line(error)}"]
        left = scan(paths.db, paths.artifacts, prefect_db=prefect_db)
    else:
        left = problems
    if args.json:
        fields = ("stage", "video_id", "key", "what")
        print(
            json.dumps(
                {
                    "problems": [{f: getattr(p, f) for f in fields} for p in problems],
                    "repaired": done,
                    "left": [{f: getattr(p, f) for f in fields} for p in left],
                }
            )
        )
    elif not paths.db.exists() and not problems:
        print(f"{paths.db}: no database yet; nothing to check")
    else:
        _print_problems(problems)
        for line in done:
            print(f"repair: {line}")
        if done and not left and any(p.stage != "prefect" for p in problems):
            print("repaired: `ringside process` (or `rerun`) computes the removed outputs again")
        elif left and args.repair:
            print(
                f"{len(left)} problem(s) a rerun cannot give back: restore the database from a "
                "backup"
            )
    return EXIT_FAILED if left else 0


def _backup(args, data_root: Path) -> int:
    from storage.backup import DATABASE, backup
    from storage.paths import data_paths

    db = data_paths(data_root).db
    if not db.exists():
        raise FileNotFoundError(f"{db}: no database yet; nothing to back up")
    manifest = backup(db, args.folder)
    rows = sum(manifest["rows"].values())
    print(
        f"backed up {db} ({manifest['bytes'] / 1e6:.1f} MB, {rows} rows in "
        f"{len(manifest['rows'])} tables) to {args.folder / DATABASE}; the artifacts stay in "
        f"{data_paths(data_root).artifacts}"
    )
    return 0


def _restore(args, data_root: Path) -> int:
    from storage.backup import restore
    from storage.paths import data_paths

    paths = data_paths(data_root)
    aside, problems = restore(paths.db, paths.artifacts, args.folder)
    kept = f"; the database it replaced is kept as {aside}" if aside else ""
    print(f"restored {paths.db} from {args.folder}{kept}")
    if problems:
        _print_problems(problems)
        print("`ringside check --repair` removes what is damaged; `process` computes it again")
        return EXIT_FAILED
    return 0


def _print_problems(problems) -> None:
    """A line per damaged output (its problems counted), then the rest one by one."""
    if not problems:
        print("no damage found: every table reads back and every artifact matches its name")
        return
    by_output: dict = {}
    for problem in problems:
        by_output.setdefault(problem.output or problem, []).append(problem)
    for found in by_output.values():
        first = found[0]
        if first.output is None:
            print(f"{first.stage}: {first.what}")
            continue
        more = f" (and {len(found) - 1} more)" if len(found) > 1 else ""
        print(
            f"{first.stage} of {first.video_id[:12]}, output {first.key[:12]}: {first.what}{more}"
        )


def _export_motion(args, data_root: Path) -> int:
    from storage.artifacts import read_bytes
    from storage.db import connect
    from storage.paths import data_paths
    from tasks.errors import BadInput
    from tasks.evaluate.export import write_folder
    from tasks.evaluate.motion_files import BOUTS, bout_files, lifted_files
    from tasks.evaluate.store import evaluation_artifacts, newest_evaluation, resolve_run
    from tasks.ingest.outputs import load_ingest
    from tasks.lift.store import load_motion, newest_lift

    paths = data_paths(data_root)
    if not paths.db.exists():
        raise BadInput(str(paths.db), "no database yet: process a video first")
    with connect(paths.db, read_only=True) as con:
        if args.video is not None:
            from flows.videos import ingested_video

            video_id = ingested_video(data_root, args.video).video_id
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
        args.out or data_root / "motion" / default,
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


def _spar(args) -> int:
    from tqdm import tqdm

    from tasks.evaluate.opponent import load_opponent
    from tasks.evaluate.spar import STILL, Partner, spar

    opponent = load_opponent(args.opponent)
    partner = Partner(None if args.partner == STILL else load_opponent(Path(args.partner)))
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
            f"{result.simulated_s:.0f} simulated s against {partner.name} in {result.wall_s:.1f} s"
            f"; falls: opponent {result.falls[0]}, partner {result.falls[1]}; damage received: "
            f"opponent {result.damage_received_n[0]:.0f} N, partner "
            f"{result.damage_received_n[1]:.0f} N"
        )
        print("time: " + ", ".join(f"{k} {v / total:.0%}" for k, v in spent.items()))
        if result.video:
            print(f"video: {result.video} ({result.frames_rendered} frames)")
    print(f"realtime_factor: {result.realtime_factor:.1f} x")
    return 0


def _pivot(rows: list[dict], row_key: str, column_key: str, cell) -> list[dict]:
    """Long rows as one row per ``row_key`` with a column per ``column_key``, in first-seen
    order; ``cell(row)`` is what a cell shows."""
    out: dict[str, dict] = {}
    for r in rows:
        out.setdefault(r[row_key], {row_key: r[row_key]})[r[column_key]] = cell(r)
    return list(out.values())


def _evaluate(args, data_root: Path) -> int:
    from flows.config import load_config
    from storage.db import connect
    from storage.paths import data_paths
    from storage.records import output_metrics
    from tasks.errors import BadInput
    from tasks.evaluate.stage import POLICIES
    from tasks.evaluate.store import evaluation_tables, resolve_run

    config = load_config(args.config, _overrides(args))
    db = data_paths(data_root).db
    if not db.exists():
        raise BadInput(str(db), "no database yet: process some footage and train first")
    with connect(db, read_only=True) as con:  # fail fast, before Prefect starts
        resolve_run(con, args.run)
    from flows.evaluate import evaluate_flow

    with _flow_server(data_root):
        summary = evaluate_flow(str(data_root), args.run, config.as_dict(), args.rerun)
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
    _print_summary([summary], data_root, False)

    def number(value) -> str:
        return "" if value is None else f"{value:.4g}"

    print("\ndamage per episode, N (MAAIP Table 1)")
    _print_table(
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
        _print_table(
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
    policies = list(POLICIES)
    print("\nstyle: simulated value (distance to the adversary's real one, 0-1)")
    style = _pivot(
        tables["style"],
        "statistic",
        "policy",
        lambda r: f"{number(r['simulated'])} ({r['distance']:.2f})",
    )
    real = {r["statistic"]: number(r["real"]) for r in tables["style"]}
    _print_table(
        [{**r, "real": real[r["statistic"]]} for r in style], ["statistic", "real", *policies]
    )
    names = {p: "style_score" + ("" if p == "adversary" else f"_{p}") for p in policies}
    scores = ", ".join(f"{p} {number(metrics.get(names[p]))}" for p in policies)
    print(f"style_score (lower is closer): {scores}")
    print("\nboxing (MSc thesis §6.1)")
    boxing = _pivot(tables["boxing"], "metric", "policy", lambda r: number(r["value"]))
    _print_table([{p: "" for p in policies} | r for r in boxing], ["metric", *policies])
    print("\nartifacts")
    _print_table(tables["artifacts"], ["name", "artifact"])
    return 0


def _datasets(args, data_root: Path) -> int:
    from storage.db import connect
    from storage.paths import data_paths
    from tasks.dataset.store import list_datasets

    db = data_paths(data_root).db
    rows = []
    if db.exists():
        with connect(db, read_only=True) as con:
            rows = list_datasets(con)
    rows = [{**r, "created_at": str(r["created_at"])} for r in rows]
    if args.json:
        print(json.dumps(rows))
    else:
        _print_table(rows, ["dataset_key", "adversary", "videos", "transitions", "created_at"])
    return 0


def _pull(data_root: Path, *, dev: bool = False) -> list[Path]:
    from storage.assets import pull
    from storage.paths import data_paths

    root = data_paths(data_root).assets
    files = pull(root, dev=dev, log=lambda line: print(line, file=sys.stderr))
    print(f"assets ready in {root} ({len(files)} files)", file=sys.stderr)
    return files


def _calibrate(args) -> int:
    import cv2

    from tasks.errors import BadInput
    from tasks.lift.camera import calibrate_chessboard, write_calibration

    try:
        board = tuple(int(v) for v in args.board.lower().split("x"))
    except ValueError:
        board = ()
    if len(board) != 2 or min(board) < 2:
        raise BadInput("--board", f"must look like 9x6 (inner corners), got {args.board!r}")
    images = []
    for path in args.images:
        image = cv2.imread(str(path))
        if image is None:
            raise BadInput(str(path), "is not an image OpenCV can read")
        images.append(image)
    sizes = {image.shape[1::-1] for image in images}
    if len(sizes) != 1:
        raise BadInput("IMAGE", f"all photos must have one size, got {sorted(sizes)}")
    K, dist, rms = calibrate_chessboard(images, board=board, square_m=args.square)
    write_calibration(args.output, K, dist, sizes.pop(), rms)
    print(
        f"fx={K[0, 0]:.1f} fy={K[1, 1]:.1f} cx={K[0, 2]:.1f} cy={K[1, 2]:.1f} "
        f"rms={rms:.3f} px -> {args.output}"
    )
    return 0


def dashboard_command(data_root: Path, *, host: str, port: int) -> list[str]:
    """The command line that serves the dashboard of ``data_root`` with Streamlit: headless (it
    opens no browser and asks no questions), without Streamlit's usage statistics."""
    from dashboards import app

    return [
        sys.executable,
        "-m",
        "streamlit",
        "run",
        app.__file__,
        "--server.headless",
        "true",
        "--server.address",
        host,
        "--server.port",
        str(port),
        "--browser.gatherUsageStats",
        "false",
        # No "Deploy" button: this dashboard is served from the analysts' own machines.
        "--client.toolbarMode",
        "minimal",
        "--",
        "--data",
        str(data_root),
    ]


def wait_until_serving(url: str, server: subprocess.Popen, timeout_s: float = 60.0) -> bool:
    """Whether the dashboard at ``url`` answers its health check before ``timeout_s``."""
    import urllib.error
    import urllib.request

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and server.poll() is None:
        try:
            with urllib.request.urlopen(f"{url}/_stcore/health", timeout=2) as answer:
                return answer.status == 200
        except (urllib.error.URLError, OSError):
            time.sleep(0.2)
    return False


@contextlib.contextmanager
def _sigterm_as_ctrl_c():
    """SIGTERM (a service manager, a test) raises KeyboardInterrupt while inside, so the
    long-running commands stop on it as on Ctrl-C, stopping what they started."""

    def stop(_signum, _frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _dashboard(args, data_root: Path) -> int:
    import webbrowser

    if not 0 < args.port < 65536:
        raise ValueError(f"--port must be between 1 and 65535, got {args.port}")
    shown_host = "localhost" if args.host in ("127.0.0.1", "0.0.0.0") else args.host
    url = f"http://{shown_host}:{args.port}"
    # Without a display, webbrowser would start a text browser in this very terminal.
    graphical = sys.platform in ("darwin", "win32") or any(
        os.environ.get(name) for name in ("DISPLAY", "WAYLAND_DISPLAY")
    )

    # A SIGTERM stops the server as Ctrl-C does, not orphaning it.
    with _sigterm_as_ctrl_c():
        server = subprocess.Popen(dashboard_command(data_root, host=args.host, port=args.port))
        print(f"dashboard of {data_root} at {url} (Ctrl-C stops it)", flush=True)
        try:
            if not args.no_browser and graphical and wait_until_serving(url, server):
                webbrowser.open(url)
            return server.wait()
        except KeyboardInterrupt:
            # Ctrl-C reached Streamlit too (same process group); a SIGTERM reached only us.
            server.send_signal(signal.SIGINT)
            try:
                server.wait(timeout=10)
            except subprocess.TimeoutExpired:
                server.kill()
                server.wait()
            print("dashboard stopped", file=sys.stderr)
            return 0


def _serve(args, data_root: Path) -> int:
    from flows import serve as served
    from flows.config import load_config
    from tasks.errors import BadInput

    if not 0 < args.port < 65536:
        raise ValueError(f"--port must be between 1 and 65535, got {args.port}")
    if args.workers < 0:
        raise ValueError(f"--workers must be 0 or more, got {args.workers}")
    watch = None
    if args.watch is None:
        for flag in ("adversary", "adversary_colour", "cron", "every", "until"):
            if getattr(args, flag) is not None:
                raise ValueError(f"--{flag.replace('_', '-')} goes with --watch DIR")
    else:
        if not args.watch.is_dir():
            raise BadInput(str(args.watch), "is not a directory (--watch)")
        if not args.adversary:
            raise ValueError("--watch needs --adversary NAME: whom the videos dropped there show")
        if args.every is not None and not args.every > 0:
            raise ValueError(f"--every must be a positive number of seconds, got {args.every}")
        watch = served.Watch(
            args.watch,
            args.adversary,
            args.adversary_colour,
            args.cron or served.DEFAULT_CRON,
            args.every,
            args.until,
        )
    running = served.served_api(data_root)
    if running is not None:
        raise ValueError(f"{data_root} is served already, at {running.removesuffix('/api')}")
    own_server = "PREFECT_API_URL" not in os.environ
    if own_server and not served.port_free(args.port):
        raise ValueError(f"--port {args.port} is in use (another server?): choose another")
    config = load_config(args.config, _overrides(args)).as_dict()
    # Set before Prefect is first imported (just below): it reads its settings then. A URL the
    # user set names their own server: serve there, start none.
    api = os.environ.setdefault("PREFECT_API_URL", f"http://127.0.0.1:{args.port}/api")
    for name, value in served.RUNNER_SETTINGS.items():
        os.environ.setdefault(name, value)
    deployments = served.deployments(data_root, config, watch)
    # SIGTERM stops it as Ctrl-C does, the server included (below); once serving, SIGTERM
    # cancels the runner instead (see serve_deployments).
    server = None
    with _sigterm_as_ctrl_c():
        try:
            if own_server:
                written = served.server_log_size(data_root)
                server = served.start_server(data_root, args.port)
                if not served.wait_until_up(api, server):
                    print(served.log_tail(data_root), file=sys.stderr)
                    why = served.startup_failure(
                        data_root, written, server.poll() is not None, served.SERVER_START_S
                    )
                    print(f"ringside: error: {why}", file=sys.stderr)
                    return EXIT_FAILED
            ui = api.removesuffix("/api")
            served.write_served(data_root, served.Served(api, ui, os.getpid()))
            print(f"Prefect UI: {ui} (Ctrl-C stops serving)", flush=True)
            print(
                f"serving {served.PIPELINE_FLOW}/{served.DEPLOYMENT} on {data_root}: "
                "`ringside schedule`, the dashboard's reruns and the UI's Run start it",
                flush=True,
            )
            if watch is not None:
                when = f"every {watch.every_s:g} s" if watch.every_s else f"on cron '{watch.cron}'"
                print(
                    f"watching {watch.folder.resolve()} {when} for new videos of {watch.adversary}",
                    flush=True,
                )
            served.serve_deployments(deployments, data_root, args.workers)
        except (KeyboardInterrupt, SystemExit):  # SystemExit: Prefect's own SIGTERM handler
            pass
        finally:
            served.clear_served(data_root, os.getpid())
            if server is not None:
                served.stop_process(server)
    print("serving stopped", file=sys.stderr)
    return 0


def _worker(args, data_root: Path) -> int:
    from flows import serve as served
    from tasks.errors import BadInput

    if args.limit < 1:
        raise ValueError(f"--limit must be at least 1, got {args.limit}")
    api = os.environ.get("PREFECT_API_URL")
    if api is None:
        raise BadInput(
            str(data_root),
            f"{served.NO_SERVER} (on another machine: set PREFECT_API_URL to its server)",
        )
    served.ensure_work_pool()
    with _sigterm_as_ctrl_c():
        worker = served.start_worker(data_root, args.limit)
        print(
            f"taking runs from work pool '{served.WORK_POOL}' of {api}, {args.limit} at a time "
            f"(log: {served.worker_log(data_root)}; Ctrl-C stops)",
            flush=True,
        )
        try:
            worker.wait()
        except KeyboardInterrupt:
            pass
        finally:
            served.stop_workers([worker])
    print("worker stopped", file=sys.stderr)
    return 0


def _schedule(args, data_root: Path) -> int:
    from datetime import datetime

    from flows import serve as served
    from flows.config import load_config
    from tasks.ingest.probe import check_file

    # Cheap checks first: a mistyped path or time fails before anything is submitted.
    for video in args.videos:
        check_file(Path(video))
    at = served.parse_when(args.at, now=datetime.now().astimezone())
    config = load_config(args.config, _overrides(args))
    parameters = served.run_parameters(
        data_root,
        args.videos,
        args.adversary,
        args.adversary_colour,
        args.notes,
        config.as_dict(),
        until=args.until,
    )
    run_id = served.submit_run(
        data_root, parameters, at=None if args.at.strip().lower() == "now" else at
    )
    ui = (served.served_api(data_root) or "").removesuffix("/api")
    url = f"{ui}/runs/flow-run/{run_id}"
    if args.json:
        print(json.dumps({"flow_run_id": run_id, "scheduled_time": at.isoformat(), "url": url}))
    else:
        print(f"flow run {run_id} runs at {at:%Y-%m-%d %H:%M:%S %Z}")
        print(f"follow it at {url}")
    return 0


def _demo(args, data_root: Path) -> int:
    from flows.config import DEMO_SETTINGS
    from storage.assets import BOXING_CLIPS, SAMPLE_VIDEO
    from storage.paths import data_paths

    _pull(data_root)
    assets = data_paths(data_root).assets
    sample = assets / SAMPLE_VIDEO
    args.config, args.until = None, None
    # The sample is two people walking: DeepMimic's punch, retargeted onto both fighters, joins
    # the motion prior's data so that the demo opponent has punches to learn.
    args.cfg__dataset__extra_clips = str(assets / BOXING_CLIPS)
    for name, value in DEMO_SETTINGS.items():
        setattr(args, "cfg__" + name.replace(".", "__"), value)
    return _process(
        args,
        data_root,
        [str(sample)],
        "demo adversary",
        None,
        "bundled two-person sample (Pose2Sim demo, camera 1)",
    )


def main(argv: list[str] | None = None) -> int:
    """One `ringside` command; the environment is left as it was found, so that a command run
    in-process (the tests, a notebook) does not hand its Prefect server (PREFECT_API_URL) to the
    next one as if the user had set it, and the server it started is stopped when it returns."""
    saved = dict(os.environ)
    try:
        return _command(sys.argv[1:] if argv is None else argv)
    finally:
        from flows.serve import stop_private_servers

        stop_private_servers()
        os.environ.clear()
        os.environ.update(saved)


def _command(raw: list[str]) -> int:
    # Settings must be in the environment before the parser's imports reach Prefect.
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--data", type=Path)
    pre.add_argument("--verbose", action="store_true")
    known, _ = pre.parse_known_args(raw)
    from storage.paths import data_paths

    data_root = data_paths(known.data).root
    prepare_environment(data_root, verbose=known.verbose)
    with _prefect_settings_of_this_command():
        return _dispatch(raw, data_root)


@contextlib.contextmanager
def _prefect_settings_of_this_command():
    """Prefect reads its settings from the environment when first imported; a later command in
    the same process (the tests, a notebook) must use its own (its data directory, its server),
    not the first command's."""
    if "prefect" not in sys.modules:
        yield
        return
    from prefect.context import SettingsContext
    from prefect.settings import Settings

    with SettingsContext(profile=SettingsContext.get().profile, settings=Settings()):
        yield


def _dispatch(raw: list[str], data_root: Path) -> int:
    args = build_parser().parse_args(raw)
    import duckdb

    from flows.serve import ServerError
    from storage.assets import AssetError
    from storage.db import DatabaseBusy, damaged_database, error_line
    from storage.paths import data_paths
    from tasks.errors import BadInput

    try:
        if args.command == "process":
            return _process(
                args, data_root, args.videos, args.adversary, args.adversary_colour, args.notes
            )
        if args.command == "status":
            return _status(args, data_root)
        if args.command == "rerun":
            return _rerun(args, data_root)
        if args.command == "pick":
            return _pick(args, data_root)
        if args.command == "metrics":
            return _metrics(args, data_root)
        if args.command == "train":
            return _train(args, data_root)
        if args.command == "curves":
            return _curves(args, data_root)
        if args.command == "export":
            return _export(args, data_root)
        if args.command == "evaluate":
            return _evaluate(args, data_root)
        if args.command == "export-motion":
            return _export_motion(args, data_root)
        if args.command == "spar":
            return _spar(args)
        if args.command == "check":
            return _check(args, data_root)
        if args.command == "backup":
            return _backup(args, data_root)
        if args.command == "restore":
            return _restore(args, data_root)
        if args.command == "datasets":
            return _datasets(args, data_root)
        if args.command == "assets":
            _pull(data_root, dev=args.dev)
            return 0
        if args.command == "calibrate":
            return _calibrate(args)
        if args.command == "config":
            from flows.config import defaults_text

            print(defaults_text(), end="")
            return 0
        if args.command == "dashboard":
            return _dashboard(args, data_root)
        if args.command == "serve":
            return _serve(args, data_root)
        if args.command == "worker":
            return _worker(args, data_root)
        if args.command == "schedule":
            return _schedule(args, data_root)
        if args.command == "demo":
            return _demo(args, data_root)
    except (BadInput, ValueError, FileNotFoundError) as error:
        print(f"ringside: error: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except (AssetError, DatabaseBusy, ServerError) as error:
        print(f"ringside: error: {error}", file=sys.stderr)
        return EXIT_FAILED
    except duckdb.Error as error:
        if not damaged_database(error):
            raise
        print(
            f"ringside: error: the database {data_paths(data_root).db} is damaged "
            f"({error_line(error)}); `ringside check` says what is affected "
            "and `ringside check --repair` recomputes it",
            file=sys.stderr,
        )
        return EXIT_FAILED
    raise AssertionError(f"unhandled command {args.command}")


def run() -> None:
    """The `ringside` command: `main`, and after an error an exit without the interpreter's
    teardown. An error raised inside a Prefect flow stays referenced by Prefect's run state,
    frames and all, until that teardown, where DuckDB's bindings then report each object
    still alive: dozens of `nanobind: leaked ...` lines after our one line. The logs are sent
    to Prefect's server first, then the exit handlers run (Prefect stops that server in one)."""
    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _interrupt)
    code = main()
    if code != 0:
        _leave(code)
    sys.exit(code)


def _leave(code: int) -> None:
    sys.stdout.flush()
    sys.stderr.flush()
    logging.shutdown()
    atexit._run_exitfuncs()
    os._exit(code)


# What stopped the command, for its last line: SIGTERM, or Ctrl-C (`_interrupt`).
_stopped_by = {"signal": signal.SIGTERM}


def _interrupt(_signum: int, _frame) -> None:
    """Ctrl-C ends a command as SIGTERM does. Inside a flow Prefect turns SIGTERM into marking
    the flow runs Crashed and cancelling their tasks; a KeyboardInterrupt, it lets wait for the
    pose stage's chunk threads (a Ctrl-C once took over 30 s to end a command). `serve` and
    `dashboard` take SIGTERM as their own stop, as they took Ctrl-C."""
    _stopped_by["signal"] = signal.SIGINT
    os.kill(os.getpid(), signal.SIGTERM)


def _stop(_signum: int, _frame) -> None:
    """SIGTERM: one line, Prefect's server stopped, out (what is committed stays committed)."""
    how = "Ctrl-C" if _stopped_by["signal"] == signal.SIGINT else "SIGTERM"
    print(
        f"ringside: error: stopped by {how}; the same command picks up where it stopped",
        file=sys.stderr,
    )
    _leave(128 + _stopped_by["signal"])


if __name__ == "__main__":
    run()
