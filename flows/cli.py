"""The ``ringside`` command: process, status, rerun, metrics, assets, demo.

Prefect reads its settings when it is first imported, so ``main`` points Prefect at the data
directory before anything imports it.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
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
    if not verbose:
        # Flow and task logs still reach the Prefect API and UI; the terminal shows our summary.
        os.environ.setdefault("PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL", "CRITICAL")


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
                help=f"{f.metadata['help']} (default {f.default})",
            )


def _overrides(args: argparse.Namespace) -> list[str]:
    return [
        f"{'.'.join(name.split('__')[1:])}={value}"
        for name, value in vars(args).items()
        if name.startswith("cfg__") and value is not None
    ]


def build_parser() -> argparse.ArgumentParser:
    from flows.config import STAGES

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
    process.add_argument("--until", choices=STAGES, help="stop after this stage")
    process.add_argument("--json", action="store_true", help="print the summary as JSON")
    _config_flags(process)

    status = commands.add_parser("status", help="what is cached, done or failed, per video")
    status.add_argument("--json", action="store_true")

    rerun = commands.add_parser("rerun", help="recompute one stage of one video, cache or not")
    rerun.add_argument("stage", choices=STAGES)
    rerun.add_argument("--video", required=True, metavar="ID", help="video id (a prefix will do)")
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

    metrics = commands.add_parser("metrics", help="each stage's metrics per video or dataset")
    metrics.add_argument("--stage", choices=[*STAGES, "train"])
    metrics.add_argument("--json", action="store_true")

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

    demo = commands.add_parser("demo", help="pull the assets and process the bundled sample")
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
    from tasks.ingest.probe import check_file

    # Cheap checks before Prefect starts, so a mistyped path fails in milliseconds.
    for video in videos:
        check_file(Path(video))
    config = load_config(args.config, _overrides(args))
    try:
        summaries = video_to_opponent(
            str(data_root),
            [str(Path(v).resolve()) for v in videos],
            adversary,
            colour,
            notes,
            config.as_dict(),
            getattr(args, "until", None),
            rerun,
        )
    except PipelineFailed as failed:
        if failed.summaries:
            _print_summary(failed.summaries, data_root, args.json)
        for line in failed.failures:
            print(f"ringside: error: {line}", file=sys.stderr)
        return EXIT_BAD_INPUT
    _print_summary(summaries, data_root, args.json)
    return 0


def _status(args, data_root: Path) -> int:
    from flows.config import STAGES
    from storage.db import connect
    from storage.paths import data_paths
    from storage.records import latest_runs

    db = data_paths(data_root).db
    rows: list[dict[str, Any]] = []
    if db.exists():
        with connect(db, read_only=True) as con:
            videos = [
                r[0]
                for r in con.execute(
                    "SELECT video_id FROM videos ORDER BY registered_at"
                ).fetchall()
            ]
            runs = {(r["video_id"], r["stage"]): r for r in latest_runs(con)}
        for video_id in videos:
            for stage in STAGES:
                run = runs.get((video_id, stage))
                rows.append(
                    {
                        "video_id": video_id,
                        "stage": stage,
                        "key": run["key"] if run else None,
                        "state": run["state"] if run else "missing",
                        "error": run["error"] if run else None,
                    }
                )
    if args.json:
        print(json.dumps(rows))
    else:
        _print_table(
            [{**r, "video_id": r["video_id"][:12], "key": (r["key"] or "")[:12]} for r in rows],
            ["video_id", "stage", "state", "key", "error"],
        )
    return 0


def _ingested(data_root: Path, video: str) -> tuple[str, str, str, str | None, str | None]:
    """(video_id, path, adversary, colour, notes) of the one ingested video ``video`` starts."""
    from storage.db import connect
    from storage.paths import data_paths
    from tasks.errors import BadInput

    db = data_paths(data_root).db
    if not db.exists():
        raise BadInput(str(db), "no database yet: process a video first")
    with connect(db, read_only=True) as con:
        found = con.execute(
            """
            SELECT p.video_id, p.path, a.name, a.colour, a.notes
            FROM ingest_probes p JOIN ingest_adversaries a USING (key, video_id)
            JOIN stage_outputs o ON o.stage = 'ingest' AND o.key = p.key AND o.video_id = p.video_id
            WHERE p.video_id LIKE ? || '%'
            QUALIFY row_number() OVER (PARTITION BY p.video_id ORDER BY o.created_at DESC) = 1
            """,
            [video],
        ).fetchall()
    if len(found) != 1:
        problem = "matches no ingested video" if not found else "matches several videos"
        raise BadInput(f"--video {video}", f"{problem}; see `ringside status`")
    return found[0]


def _rerun(args, data_root: Path) -> int:
    _, path, name, colour, notes = _ingested(data_root, args.video)
    return _process(args, data_root, [path], name, colour, notes, rerun=[args.stage])


def _pick(args, data_root: Path) -> int:
    from storage.db import connect, utcnow
    from storage.paths import data_paths
    from tasks.errors import BadInput

    video_id, path, name, colour, notes = _ingested(data_root, args.video)
    with connect(data_paths(data_root).db) as con:
        tracks = sorted(
            row[0]
            for row in con.execute(
                "SELECT DISTINCT track FROM pose_tracks WHERE video_id = ?", [video_id]
            ).fetchall()
        )
        if args.track not in tracks:
            raise BadInput(
                f"--track {args.track}",
                f"video {video_id[:12]} has no such track; tracks: {tracks}",
            )
        con.execute("INSERT INTO pose_picks VALUES (?, ?, ?)", [video_id, args.track, utcnow()])
    args.until = None
    return _process(args, data_root, [path], name, colour, notes)


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
    from flows.train import train_flow

    config = load_config(args.config, _overrides(args))
    summary = train_flow(str(data_root), args.dataset, config.as_dict(), args.rerun)
    _print_summary([summary], data_root, args.json)
    return 0


def _curves(args, data_root: Path) -> int:
    from storage.db import connect
    from storage.paths import data_paths
    from tasks.train.run import CURVES, learning_curves

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


def _demo(args, data_root: Path) -> int:
    from storage.assets import SAMPLE_VIDEO
    from storage.paths import data_paths

    _pull(data_root)
    sample = data_paths(data_root).assets / SAMPLE_VIDEO
    args.config, args.until = None, None
    return _process(
        args,
        data_root,
        [str(sample)],
        "demo adversary",
        None,
        "bundled two-person sample (Pose2Sim demo, camera 1)",
    )


def main(argv: list[str] | None = None) -> int:
    raw = sys.argv[1:] if argv is None else argv
    # Settings must be in the environment before the parser's imports reach Prefect.
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--data", type=Path)
    pre.add_argument("--verbose", action="store_true")
    known, _ = pre.parse_known_args(raw)
    from storage.paths import data_paths

    data_root = data_paths(known.data).root
    prepare_environment(data_root, verbose=known.verbose)

    args = build_parser().parse_args(raw)
    from storage.assets import AssetError
    from storage.db import DatabaseBusy
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
        if args.command == "demo":
            return _demo(args, data_root)
    except (BadInput, ValueError, FileNotFoundError) as error:
        print(f"ringside: error: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except (AssetError, DatabaseBusy) as error:
        print(f"ringside: error: {error}", file=sys.stderr)
        return EXIT_FAILED
    raise AssertionError(f"unhandled command {args.command}")


if __name__ == "__main__":
    sys.exit(main())
