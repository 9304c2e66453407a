"""The synthetic-adversary command: DeepMimic's clips on two bodies as a regular dataset."""

from __future__ import annotations

import dataclasses

from flows.cli.environment import flow_server
from flows.cli.parser import overrides
from flows.cli.tables import print_summary
from storage.paths import DataPaths


def synthetic_adversary_command(args, paths: DataPaths) -> int:
    from flows.config import load_config
    from flows.dataset import synthetic_adversary_flow
    from tasks.dataset.synthetic import SyntheticConfig, clip_files, dataset_config

    config = load_config(args.config, overrides(args))
    # Checked before Prefect starts, so that a missing clip or body fails in a second.
    clip_files(paths.assets)
    settings = {
        f.name: getattr(args, f.name)
        for f in dataclasses.fields(SyntheticConfig)
        if getattr(args, f.name) is not None
    }
    dataset_config(config.dataset, SyntheticConfig(**settings))
    bones = _bodies(args, paths)
    with flow_server(paths):
        summaries = synthetic_adversary_flow(
            str(paths.root),
            args.name,
            {role: dataclasses.asdict(b) for role, b in bones.items()},
            settings,
            config.as_dict(),
            args.rerun,
        )
    print_summary(summaries, paths, args.json)
    return 0


def _bodies(args, paths: DataPaths):
    """The two bodies: of ``--bones FILE``, of ``--video ID``'s lift, or of the bundled
    sample's lift (the default)."""
    from storage.assets import SAMPLE_VIDEO
    from storage.db import connect
    from storage.files import sha256_file
    from tasks.dataset.synthetic import lifted_bones, read_bones_file
    from tasks.errors import BadInput
    from tasks.ingest.store import ingested_video

    if args.bones is not None:
        return read_bones_file(args.bones)
    if args.video is None:
        sample = paths.assets / SAMPLE_VIDEO
        if not sample.is_file():
            raise BadInput(
                str(sample), "missing: the bundled sample is an asset (`ringside assets pull`)"
            )
        video_id, what = sha256_file(sample), f"the bundled sample {sample}"
    else:
        video_id, what = args.video, f"--video {args.video}"
    if not paths.db.exists():
        raise BadInput(
            what,
            f"has not been lifted in {paths.root} (no database): run `ringside process` on it "
            "first (`--until lift` will do), or give the bodies with --bones FILE",
        )
    with connect(paths.db, read_only=True) as con:
        if args.video is not None:
            video_id = ingested_video(con, args.video).video_id
        return lifted_bones(con, video_id, what)
