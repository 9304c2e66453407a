"""The command line: every command's arguments and the settings' override flags."""

from __future__ import annotations

import argparse
from pathlib import Path

# Short flags for the settings an analyst gives per video, beside their --SECTION-NAME ones.
ALIASES: dict[tuple[str, ...], str] = {
    ("lift", "adversary_height_m"): "--adversary-height",
    ("lift", "opponent_height_m"): "--opponent-height",
}


def config_flags(parser: argparse.ArgumentParser) -> None:
    from flows.config import sections
    from tasks.config import leaf_fields

    parser.add_argument("--config", type=Path, help="TOML config (default: ./ringside.toml)")
    for section, cls in sections().items():
        group = parser.add_argument_group(f"{section} settings (override {section} in the config)")
        for path, f in leaf_fields(cls, (section,)):
            group.add_argument(
                "--" + "-".join(path).replace("_", "-"),
                *[ALIASES[path]] if path in ALIASES else [],
                dest="cfg__" + "__".join(path),
                metavar="VALUE",
                help=f"{f.metadata['help']} (default {f.default})".replace("%", "%%"),
            )


def overrides(args: argparse.Namespace) -> list[str]:
    return [
        f"{'.'.join(name.split('__')[1:])}={value}"
        for name, value in vars(args).items()
        if name.startswith("cfg__") and value is not None
    ]


def build_parser() -> argparse.ArgumentParser:
    from flows.postgres import DEFAULT_PORT
    from tasks.registry import names

    stages = names()

    parser = argparse.ArgumentParser(
        prog="ringside",
        description="Turn an adversary's fight footage into a sparring opponent.",
    )
    parser.add_argument(
        "--data", type=Path, help="data directory (default: $RINGSIDE_DATA or ./data)"
    )
    parser.add_argument(
        "--results",
        metavar="URL",
        help="where the results are: ducklake:postgres:dbname=NAME host=HOST port=PORT "
        "user=USER for a DuckLake catalog several machines write at once (with --shared; "
        "`ringside postgres --lake` prints one); default $RINGSIDE_RESULTS, else the data "
        "directory's DuckDB file",
    )
    parser.add_argument(
        "--shared",
        type=Path,
        metavar="DIR",
        help="with a DuckLake --results: the folder every machine reaches at this path, for "
        "the lake's data files and the artifacts (default $RINGSIDE_SHARED)",
    )
    parser.add_argument("--verbose", action="store_true", help="show Prefect's logs too")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    process = commands.add_parser("process", help="run the pipeline on videos now")
    process.add_argument("videos", nargs="+", metavar="VIDEO")
    process.add_argument("--adversary", required=True, metavar="NAME", help="who the adversary is")
    process.add_argument("--adversary-colour", metavar="COLOUR", help="trunk colour or #rrggbb")
    process.add_argument("--notes", help="free text kept with the video")
    process.add_argument("--until", choices=stages, help="stop after this stage")
    process.add_argument("--json", action="store_true", help="print the summary as JSON")
    config_flags(process)

    status = commands.add_parser("status", help="what is cached, done or failed, per video")
    status.add_argument("--json", action="store_true")

    rerun = commands.add_parser(
        "rerun", help="recompute one stage of one video (and what depends on it), cache or not"
    )
    rerun.add_argument("stage", choices=stages)
    rerun.add_argument("--video", required=True, metavar="ID", help="video id (a prefix will do)")
    rerun.add_argument("--until", choices=stages, help="stop after this stage")
    rerun.add_argument("--json", action="store_true")
    config_flags(rerun)

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
    pick.add_argument("--until", choices=stages, help="stop after this stage")
    pick.add_argument("--json", action="store_true")
    config_flags(pick)

    train = commands.add_parser(
        "train", help="train the fighters' policies on a dataset (MAAIP; resumes if killed)"
    )
    train.add_argument("--dataset", required=True, metavar="KEY", help="see `ringside datasets`")
    train.add_argument("--rerun", action="store_true", help="train again from scratch")
    train.add_argument("--json", action="store_true")
    config_flags(train)

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
    export.add_argument(
        "--clip",
        metavar="NAME",
        help="a tracker run's clip to play, one of DeepMimic's (`tasks.deepmimic`: walk, punch, "
        "...); a tracker run needs one, a MAAIP run takes none",
    )
    export.add_argument(
        "--matched",
        action="store_true",
        help="a tracker run as the matched opponent: it plays the fighter's own train footage "
        "(the clips the tracker finished), picked by the partner-aware motion matcher",
    )
    export.add_argument(
        "--matched-motion",
        choices=("footage", "replay"),
        default="footage",
        help="with --matched, what the matcher picks from: the footage as filmed, or the "
        "tracker's own replay of it (each train clip played from its first frame, up to half a "
        "second before a fall; physically valid motion, with its body error per frame)",
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

    live = commands.add_parser(
        "spar-server",
        help="serve an exported opponent live over WebSocket, with a viewer in the browser "
        "(docs/spar-protocol.md)",
    )
    live.add_argument("opponent", type=Path, help="an opponent folder (`ringside export`)")
    live.add_argument(
        "--host",
        default="127.0.0.1",
        metavar="ADDRESS",
        help="address to listen on (default 127.0.0.1; any other needs a token)",
    )
    live.add_argument("--port", type=int, default=8765, metavar="N", help="default 8765; 0: any")
    live.add_argument(
        "--token",
        metavar="TEXT",
        help="what clients must send in their hello (default: none on 127.0.0.1, a random "
        "one printed at start on any other address)",
    )
    live.add_argument(
        "--partner",
        type=Path,
        metavar="FOLDER",
        help="an opponent folder whose policy drives the partner's limbs in commands mode (e.g. "
        "`ringside export --agent opponent`; its pelvis is still steered by the commands); "
        "default: the partner holds its guard",
    )
    live.add_argument(
        "--max-sessions", type=int, default=8, metavar="N", help="concurrent sessions (8)"
    )

    evaluate = commands.add_parser(
        "evaluate",
        help="judge a training run: damage, style and boxing tables, ONNX export, a rendered bout",
    )
    evaluate.add_argument(
        "--run", required=True, metavar="KEY", help="training key (a prefix will do)"
    )
    evaluate.add_argument("--rerun", action="store_true", help="evaluate again, cached or not")
    evaluate.add_argument("--json", action="store_true")
    config_flags(evaluate)

    metrics = commands.add_parser("metrics", help="each stage's metrics per video or dataset")
    metrics.add_argument("--stage", choices=stages)
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
        "datasets", help="assembled training datasets: key, adversary, videos, transitions, verdict"
    )
    datasets.add_argument("--json", action="store_true")

    synthetic_parser(commands)

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
        "--until", choices=stages, help="stop after this stage for videos found in DIR"
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
    config_flags(serve)

    postgres = commands.add_parser(
        "postgres",
        help="start a PostgreSQL cluster for Prefect's server in DATA/postgres; print its URL",
        description="Makes a PostgreSQL cluster in DATA/postgres the first time (as root, owned "
        "and run by the `postgres` user: PostgreSQL refuses to run as root), starts it on "
        "127.0.0.1 with a database `prefect`, and prints the setting that gives it to "
        "`ringside serve`. Run again while it runs, it prints that setting again.",
    )
    postgres.add_argument(
        "--port",
        type=int,
        default=DEFAULT_PORT,
        metavar="N",
        help=f"the cluster's port (default {DEFAULT_PORT})",
    )
    postgres.add_argument("--stop", action="store_true", help="stop the cluster (stop serve first)")
    postgres.add_argument(
        "--lake",
        action="store_true",
        help="print the --results setting of the cluster's DuckLake catalog (the database "
        "`ringside`) instead of Prefect's",
    )

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
    schedule.add_argument("--until", choices=stages, help="stop after this stage")
    schedule.add_argument("--json", action="store_true")
    config_flags(schedule)

    demo = commands.add_parser(
        "demo", help="pull the assets and turn the bundled sample into an opponent"
    )
    demo.add_argument("--json", action="store_true")
    return parser


def synthetic_parser(commands) -> None:
    """`ringside synthetic-adversary`: its options, the settings of `SyntheticConfig` among
    them."""
    import dataclasses

    from tasks.dataset.synthetic import SyntheticConfig

    synthetic = commands.add_parser(
        "synthetic-adversary",
        help="DeepMimic's walk, the walker's turns and the punch on the sample's two bodies, as a "
        "dataset to train on (judging training apart from the lift's noise)",
        description="Retargets DeepMimic's walk and punch and the walker's straight walk and four "
        "turns onto two bodies (by default those the lift measured for the bundled sample's "
        "fighters: run `ringside process` on the sample first, or give --video or --bones), "
        "plays each clip once per round as an exchange (the opponent performs it reversed, "
        "placed facing the adversary), cuts 1-second windows, holds 30 %% of them out as the "
        "validation split, and records it as a regular dataset: its key is what `ringside "
        "train --dataset` takes. Cached: run again, it does no work (docs/dataset.md).",
    )
    synthetic.add_argument(
        "--name",
        default="synthetic adversary",
        metavar="NAME",
        help="the dataset's adversary (default: 'synthetic adversary')",
    )
    bodies = synthetic.add_mutually_exclusive_group()
    bodies.add_argument(
        "--video",
        metavar="ID",
        help="the two bodies of this lifted video (a prefix will do; default: the bundled sample)",
    )
    bodies.add_argument(
        "--bones",
        type=Path,
        metavar="FILE",
        help='the two bodies from JSON: {"adversary": {"thigh": 0.43, ...}, "opponent": {...}} '
        "(a bone left out takes its default)",
    )
    for f in dataclasses.fields(SyntheticConfig):
        synthetic.add_argument(
            "--" + f.name.replace("_", "-"),
            type=type(f.default),
            metavar="VALUE",
            help=f"{f.metadata['help']} (default {f.default})".replace("%", "%%"),
        )
    synthetic.add_argument("--rerun", action="store_true", help="compute again, cached or not")
    synthetic.add_argument("--json", action="store_true")
    config_flags(synthetic)
