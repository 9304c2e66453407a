"""What every page of the dashboard uses: reading the database (a short read-only connection per
render, waiting for the pipeline's writes), choosing a video or an output, labels, number
formats, videos and the colours of roles and fighters."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any, TypeVar

import altair as alt
import duckdb
import pandas as pd
import streamlit as st

from dashboards import queries
from storage.artifacts import NotAnArtifact, artifact_path, hashes_to_name
from storage.db import (
    CatalogUnreachable,
    DatabaseBusy,
    connect,
    damaged_database,
    error_line,
    utcnow,
)
from storage.paths import DataPaths
from tasks import registry
from tasks.errors import BadInput
from tasks.registry import Subject

# Where a render keeps the data directory its script was given (`dashboards.app.open_data`).
DATA = "ringside_data"
# A page waits this long for the pipeline to let go of the database, then says so: a writer
# holds it for seconds at most, and an analyst should not stare at a blank page meanwhile.
LOCK_WAIT_S = 10.0

# Chart axes' numbers (d3-format): 4 significant digits without trailing zeros, so that 80 is
# not "8e+1" and an all-zero axis not "0.000000".
AXIS_FORMAT = ".4~g"

# Each fighter's colour in every chart: the corners of a boxing ring.
FIGHTER_COLOURS = alt.Scale(domain=["adversary", "opponent"], range=["#c8102e", "#1f5fbf"])

ROLE_COLOURS = alt.Scale(
    domain=["adversary", "opponent", "other"], range=["#c8102e", "#1f5fbf", "#aaaaaa"]
)

# What an empty page tells the analyst to run.
PROCESS_HINT = "run `ringside process VIDEO --adversary NAME` (or `ringside demo`)"

TRAIN_HINT = "run `ringside train --dataset KEY` (`ringside datasets` lists the keys)"

HINTS = {
    "train": TRAIN_HINT,
    "evaluate": "run `ringside evaluate --run KEY` (the Training page lists the runs)",
}

# The last line every page writes: the browser tests wait for it to know the page is drawn.
READ_AT = "Data read at"

T = TypeVar("T")


def format_value(value: float | None) -> str:
    """How the dashboard writes every number: 4 significant digits, a dash for none."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.4g}"


def data() -> DataPaths:
    """The data directory this dashboard shows, as its script found it for this render
    (`dashboards.app.open_data`)."""
    return st.session_state[DATA]


def read(read_with: Callable[[duckdb.DuckDBPyConnection], T]) -> T | None:
    """``read_with``'s result on a fresh read-only connection, closed before the page draws; None
    after telling the analyst why there is nothing to read."""
    db = data().db
    if not db.exists():
        where = db.parent if isinstance(db, Path) else db
        st.info(f"No database yet in `{where}`: {PROCESS_HINT}.")
        return None
    try:
        with connect(db, read_only=True, wait_s=LOCK_WAIT_S) as con:
            return read_with(con)
    except CatalogUnreachable as error:
        st.warning(f"{error}; press Reload once PostgreSQL is back.")
        return None
    except DatabaseBusy:
        st.warning(
            f"The pipeline has held the database for over {LOCK_WAIT_S:.0f} s; "
            "press Reload in a moment."
        )
        return None
    except duckdb.Error as error:
        if not damaged_database(error):
            raise
        st.error(
            f"The database `{db}` is damaged ({error_line(error)}): "
            "`ringside check` says what is affected, `ringside check --repair` recomputes it."
        )
        return None


def read_rows(
    read_with: Callable[[duckdb.DuckDBPyConnection], list[T]], empty: str
) -> list[T] | None:
    """``read_with``'s rows; None when there are none, after saying ``empty`` and finishing the
    page, or when the read failed (`read` has said why)."""
    rows = read(read_with)
    if rows is not None and not rows:
        st.info(empty)
        finish_page()
        return None
    return rows


def finish_page() -> None:
    st.caption(f"{READ_AT} {datetime.now():%H:%M:%S} from `{data().db}`.")


def artifact_file(name: str | None) -> Path | None:
    """Where the artifact ``name`` lives, or None (after saying so) when it is not there or its
    bytes do not hash to its name."""
    if name is None:
        return None
    try:
        path = artifact_path(data().artifacts, name)
    except NotAnArtifact as error:
        st.error(f"{error}; `ringside check` lists what the database names wrongly.")
        return None
    try:
        stat = path.stat()
    except FileNotFoundError:
        st.warning(f"Artifact `{name}` is missing from the artifact store.")
        return None
    if not intact(path, stat.st_size, stat.st_mtime_ns):
        st.warning(
            f"Artifact `{name}` is corrupt (its bytes do not hash to its name) and is not shown: "
            "`ringside check --repair` removes it, and the next `ringside process` computes it "
            "again."
        )
        return None
    return path


# Keyed by size and modification time as well as the path, so that each render does not hash
# the file again (a 500 MB video takes seconds), but a file written anew is.
@functools.lru_cache(maxsize=4096)
def intact(path: Path, size: int, mtime_ns: int) -> bool:
    """Whether the artifact file ``path`` (of ``size`` bytes, modified at ``mtime_ns``) hashes
    to its name."""
    return hashes_to_name(path)


def show_video(name: str | None, caption: str) -> None:
    """An H.264 MP4 from the artifact store, with a caption; browsers play it in place."""
    path = artifact_file(name)
    if path is not None:
        st.video(str(path), width=720)
        st.caption(caption)


def choose_video(videos: Sequence[Mapping[str, Any]]) -> str:
    """The video the page is about, chosen by the analyst (``?video=`` in the URL)."""
    labels = video_labels(videos)
    return choose("Video", list(labels), "video", format_func=labels.get)


def video_review(
    stage: str, review_with: Callable[[duckdb.DuckDBPyConnection, str], T | None]
) -> tuple[str, T] | None:
    """The video a per-video page is about, chosen by the analyst, and ``review_with``'s reading
    of its newest ``stage`` output; None, after saying why, when there is nothing to show."""
    videos = read_rows(queries.videos, f"No video yet: {PROCESS_HINT}.")
    if videos is None:
        return None
    video = choose_video(videos)
    found = read(lambda con: (review_with(con, video),))  # None only when the read failed
    if found is None:
        return None
    if found[0] is None:
        st.info(f"This video has no {stage} output yet: {PROCESS_HINT}.")
        finish_page()
        return None
    return video, found[0]


def choose(label: str, options: Sequence[str], param: str, **kwargs: Any) -> str:
    """A select box whose choice is also in the page's URL (``?param=value``), so a view can be
    linked to and reloaded."""
    wanted = st.query_params.get(param)
    index = list(options).index(wanted) if wanted in options else 0
    choice = st.selectbox(label, options, index=index, **kwargs)
    st.query_params[param] = choice
    return choice


def plural(count: int, noun: str, nouns: str | None = None) -> str:
    """``count`` and the noun, singular or plural (``nouns``, else ``noun`` + s)."""
    return f"{count} {noun if count == 1 else nouns or noun + 's'}"


def video_labels(videos: Sequence[Mapping[str, Any]]) -> dict[str, str]:
    """Video id -> "file name · short id", how the dashboard names a video."""
    return {
        v[
            "video_id"
        ]: f"{Path(v['path']).name if v['path'] else '?'} · {queries.short(v['video_id'])}"
        for v in videos
    }


def dataset_labels(sets: Sequence[Mapping[str, Any]]) -> dict[str, str]:
    """Dataset key -> "dataset short key · adversary", how the dashboard names a dataset."""
    return {d["dataset_key"]: f"{queries.short(d['dataset_key'])} · {d['adversary']}" for d in sets}


def output_labels(
    stage: str,
    outputs: Sequence[str],
    videos: Sequence[Mapping[str, Any]],
    sets: Sequence[Mapping[str, Any]],
) -> dict[str, str]:
    """Each output id of ``stage`` -> its column label on the Stages page: a video as
    `video_labels` names it, for a stage of a dataset (training) as `dataset_labels` does, else
    the short id."""
    of_datasets = registry.stage(stage).subject is Subject.DATASET
    known = dataset_labels(sets) if of_datasets else video_labels(videos)
    return {output: known.get(output, queries.short(output)) for output in outputs}


def numbers_table(frame: pd.DataFrame) -> Any:
    """``frame`` with its numeric columns written as `format_value` writes them."""
    return frame.style.format(format_value, subset=list(frame.select_dtypes("number").columns))


def follow_run(paths: DataPaths, video: str, stage: str, parameters: Callable[[], dict]) -> bool:
    """Submit a pipeline run of ``video`` with ``parameters()`` to the served deployment and
    remember it for `rerun_progress`; False (after saying why) if Prefect refused it."""
    from flows.launch import submit_run

    started = utcnow()
    try:
        run_id = submit_run(paths, parameters())
    except BadInput as error:
        st.error(f"Could not start the run: {error}")
        return False
    st.session_state.setdefault("reruns", []).append(
        {"flow_run": run_id, "video_id": video, "stage": stage, "started": started}
    )
    return True
