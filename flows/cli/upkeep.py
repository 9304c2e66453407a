"""Commands that look after the data directory and its inputs: check, backup, restore, assets,
calibrate."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from flows.cli.environment import EXIT_FAILED
from flows.cli.tables import print_problems
from storage.paths import DataPaths, Lake


def check_command(args, paths: DataPaths) -> int:
    import duckdb
    from tqdm import tqdm

    from flows.serve import prefect_database
    from storage.check import repair, scan
    from storage.db import error_line

    prefect_db = prefect_database()
    # A lake has no file of blocks nor write-ahead log: its Parquet files are what is checked.
    lake = isinstance(paths.db, Lake)
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
    elif lake and not problems:
        print(
            "no damage found: every table reads back, every Parquet file the lake's catalog "
            "names is there and reads, and every file of the artifact store matches its name"
        )
    else:
        print_problems(problems)
        wal = None if lake else paths.db.with_name(paths.db.name + ".wal")
        if wal is not None and wal.exists():
            print(
                f"not verified block by block: {wal.name}, the log of the last writes; DuckDB "
                "reads it whole as it opens the database, which opened"
            )
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


def backup_command(args, paths: DataPaths) -> int:
    from storage.backup import DATABASE, backup

    db = paths.db
    if not db.exists():
        raise FileNotFoundError(f"{db}: no database yet; nothing to back up")
    manifest = backup(db, args.folder)
    rows = sum(manifest["rows"].values())
    # A lake's backup is one of its snapshots, named so that time travel reaches it too.
    at = f" at snapshot {manifest['snapshot']}" if isinstance(db, Lake) else ""
    print(
        f"backed up {db}{at} ({manifest['bytes'] / 1e6:.1f} MB, {rows} rows in "
        f"{len(manifest['rows'])} tables) to {args.folder / DATABASE}; the artifacts stay in "
        f"{paths.artifacts}"
    )
    return 0


def restore_command(args, paths: DataPaths) -> int:
    from storage.backup import restore

    aside, problems = restore(paths.db, paths.artifacts, args.folder)
    # A lake keeps what it replaced as a snapshot, not a file.
    if isinstance(paths.db, Lake):
        kept = (
            f"; the lake as it was is its snapshot {aside}, readable by time travel "
            f"(SELECT ... FROM TABLE AT (VERSION => {aside}))"
        )
    else:
        kept = f"; the database it replaced is kept as {aside}" if aside else ""
    print(f"restored {paths.db} from {args.folder}{kept}")
    if problems:
        print_problems(problems)
        print("`ringside check --repair` removes what is damaged; `process` computes it again")
        return EXIT_FAILED
    return 0


def pull_assets(paths: DataPaths, *, dev: bool = False) -> list[Path]:
    from storage.assets import pull

    root = paths.assets
    files = pull(root, dev=dev, log=lambda line: print(line, file=sys.stderr))
    print(f"assets ready in {root} ({len(files)} files)", file=sys.stderr)
    return files


def assets_command(args, paths: DataPaths) -> int:
    pull_assets(paths, dev=args.dev)
    return 0


def config_command(_args, _paths: DataPaths) -> int:
    from flows.config import defaults_text

    print(defaults_text(), end="")
    return 0


def calibrate_command(args, _paths: DataPaths) -> int:
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
