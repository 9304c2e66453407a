"""The analysts' dashboard, a Streamlit app: `ringside dashboard` serves it.

Pages: Overview (every video's stages), Stages (one stage's metrics across videos), Dataset (the
adversary's statistics) and Training (learning curves). Each render opens its own short
read-only connection, reads everything the page shows and closes it before drawing, so the
pipeline can write between two renders. A page whose tables are empty says which command
fills them.

By hand: ``streamlit run dashboards/app.py -- --data DIR`` (default ``$RINGSIDE_DATA`` or
``./data``).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Mapping, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any, TypeVar

import altair as alt
import duckdb
import pandas as pd
import streamlit as st

from dashboards import queries
from flows.config import PIPELINE_STAGES, STAGES
from storage.artifacts import NotAnArtifact, artifact_path
from storage.db import DatabaseBusy, connect, damaged_database, error_line, utcnow
from storage.paths import data_paths
from tasks.dataset.labels import HANDS, KINDS
from tasks.dataset.statistics import DISTRIBUTIONS, SCALARS
from tasks.errors import BadInput
from tasks.pose.store import record_pick

# A page waits this long for the pipeline to let go of the database, then says so: a writer
# holds it for seconds at most, and an analyst should not stare at a blank page meanwhile.
LOCK_WAIT_S = 10.0
STATE_COLOURS = {
    "done": "#d4f0da",
    "cached": "#dde9fa",
    "failed": "#f8d3d2",
    "running": "#fff3c4",
    "interrupted": "#fbe0c4",
    "missing": "#eeeeee",
}
# The statistics shown as headline numbers on the Dataset page, with their labels.
HEADLINES = {
    "punches_per_min": "Punches / min",
    "distance_mean_m": "Distance (m)",
    "guard_height_mean_m": "Guard height (m)",
    "orthodox_share": "Orthodox share",
    "steps_per_min": "Steps / min",
    "minutes": "Footage (min)",
}
# The Dataset page's histograms: distribution (see DISTRIBUTIONS) -> title.
HISTOGRAMS = {
    "distance_m": "Distance to the opponent, per frame (m)",
    "guard_height_m": "Wrists above the nose, per frame (m)",
    "punch_duration_s": "Punch duration (s)",
    "step_length_m": "Step length (m)",
}
# The Training page's charts: title -> curves drawn together.
CURVE_CHARTS: dict[str, dict[str, str]] = {
    "Episode length (s)": {"episode_length_s": "episode length"},
    "Discriminator rewards": {
        "reward_motion": "motion prior",
        "reward_interaction": "interaction prior",
        "reward_total": "weighted total",
    },
    "Falls per minute": {"falls_per_min": "falls per minute"},
    "Discriminators' accuracy on the policy's motion": {
        "motion_accuracy_fake": "motion prior",
        "interaction0_accuracy_fake": "interaction prior, agent 0",
    },
}
# Distributions that are one number seen from either fighter, drawn once.
SAME_FOR_BOTH = {"distance_m"}
# Chart axes' numbers (d3-format): 4 significant digits without trailing zeros, so that 80 is
# not "8e+1" and an all-zero axis not "0.000000".
AXIS_FORMAT = ".4~g"
# Each fighter's colour in every chart: the corners of a boxing ring.
FIGHTER_COLOURS = alt.Scale(domain=["adversary", "opponent"], range=["#c8102e", "#1f5fbf"])
ROLE_COLOURS = alt.Scale(
    domain=["adversary", "opponent", "other"], range=["#c8102e", "#1f5fbf", "#aaaaaa"]
)
# The Training page's headline numbers: the newest block's means of these.
TILES = {
    "episode_length_s": "Episode length (s)",
    "reward_motion": "Motion reward",
    "reward_interaction": "Interaction reward",
    "falls_per_min": "Falls per minute",
}
# The Evaluation page's headline numbers.
EVALUATION_TILES = {
    "style_score": "Style: trained adversary",
    "style_score_untrained": "Style: untrained policy",
    "style_score_opponent": "Style: trained partner",
    "style_score_still": "Style: standing still in guard",
    "falls_per_min": "Bouts ended by a fall / min",
    "onnx_max_abs_diff": "ONNX max difference",
}
# What the Stages page compares, for the stages whose outputs are not per video.
COMPARED = {"train": "datasets", "evaluate": "training runs"}
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


def data_root(argv: Sequence[str]) -> Path:
    """The data directory: ``--data DIR`` among the script's arguments, else
    ``$RINGSIDE_DATA``, else ``./data``."""
    # Streamlit passes the script its own arguments; anything else there (pytest's, when a test
    # runs a page) is not ours to refuse.
    parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    parser.add_argument("--data", type=Path)
    known, _ = parser.parse_known_args(list(argv))
    return data_paths(known.data).root


def database() -> Path:
    return data_paths(data_root(sys.argv[1:])).db


def read(read_with: Callable[[duckdb.DuckDBPyConnection], T]) -> T | None:
    """``read_with``'s result on a fresh read-only connection, closed before the page draws; None
    after telling the analyst why there is nothing to read."""
    db = database()
    if not db.exists():
        st.info(f"No database yet in `{db.parent}`: {PROCESS_HINT}.")
        return None
    try:
        with connect(db, read_only=True, wait_s=LOCK_WAIT_S) as con:
            return read_with(con)
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
    st.caption(f"{READ_AT} {datetime.now():%H:%M:%S} from `{database()}`.")


def artifact_file(name: str | None) -> Path | None:
    """Where the artifact ``name`` lives, or None (after saying so) when it is not there."""
    if name is None:
        return None
    try:
        path = artifact_path(data_paths(data_root(sys.argv[1:])).artifacts, name)
    except NotAnArtifact as error:
        st.error(f"{error}; `ringside check` lists what the database names wrongly.")
        return None
    if not path.exists():
        st.warning(f"Artifact `{name}` is missing from the artifact store.")
        return None
    return path


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
    `video_labels` names it, for train a dataset as `dataset_labels` does, else the short id."""
    known = dataset_labels(sets) if stage == "train" else video_labels(videos)
    return {output: known.get(output, queries.short(output)) for output in outputs}


def numbers_table(frame: pd.DataFrame) -> Any:
    """``frame`` with its numeric columns written as `format_value` writes them."""
    return frame.style.format(format_value, subset=list(frame.select_dtypes("number").columns))


def overview_page() -> None:
    st.title("Overview")
    found = read(
        lambda con: (
            queries.videos(con),
            queries.stage_overview(con),
            queries.opponent_overview(con),
        )
    )
    if found is None:
        return
    videos, states, opponents = found
    if not videos:
        st.info(f"No video yet: {PROCESS_HINT}.")
        finish_page()
        return
    labels = video_labels(videos)
    adversary = {v["video_id"]: v["adversary"] or "" for v in videos}
    matrix = queries.state_matrix(states)
    matrix.insert(0, "adversary", [adversary[v] for v in matrix.index])
    matrix.index = [labels[v] for v in matrix.index]
    st.subheader("Each video's stages")
    st.table(
        matrix.style.map(lambda s: f"background-color: {STATE_COLOURS.get(s, '')}", list(STAGES))
    )
    st.caption(
        "done: computed by its newest run; cached: its newest run reused an output; running: "
        "computing now; interrupted: its process stopped mid-stage (killed or crashed), rerun "
        "it; failed: see below; missing: not run yet."
    )
    st.subheader("Newest run of each stage")
    runs = pd.DataFrame(
        {
            "video": [labels[r["video_id"]] for r in states],
            "stage": [r["stage"] for r in states],
            "state": [r["state"] for r in states],
            "key": [queries.short(r["key"]) for r in states],
            "ran at": [f"{r['ran_at']:%Y-%m-%d %H:%M:%S}" if r["ran_at"] else "" for r in states],
            "computed in (s)": [format_value(r["seconds"]) for r in states],
            "why it failed": [r["error"] or "" for r in states],
        }
    )
    if not runs["why it failed"].any():
        runs = runs.drop(columns="why it failed")
    st.table(runs, hide_index=True)
    opponent_section(opponents)
    rerun_section(videos)
    finish_page()


def opponent_section(rows: Sequence[Mapping[str, Any]]) -> None:
    """Training on each adversary's dataset and the evaluation of each finished run."""
    st.subheader("Training and evaluation")
    if not rows:
        st.info(f"No dataset yet: {PROCESS_HINT}.")
        return
    table = pd.DataFrame(
        {
            "adversary": [r["adversary"] for r in rows],
            "stage": [r["stage"] for r in rows],
            "of": [
                ("dataset " if r["stage"] == "train" else "run ") + queries.short(r["video_id"])
                for r in rows
            ],
            "state": [r["state"] for r in rows],
            "key": [queries.short(r["key"]) if r["key"] else "" for r in rows],
            "ran at": [f"{r['ran_at']:%Y-%m-%d %H:%M:%S}" if r["ran_at"] else "" for r in rows],
            "computed in (s)": [format_value(r["seconds"]) for r in rows],
            "why it failed": [r["error"] or "" for r in rows],
        }
    )
    if not table["why it failed"].any():
        table = table.drop(columns="why it failed")
    st.table(
        table.style.map(lambda s: f"background-color: {STATE_COLOURS.get(s, '')}", ["state"]),
        hide_index=True,
    )
    st.caption(
        "Training runs on a dataset (every processed video of the adversary), evaluation on a "
        "finished training run; the Training and Evaluation pages show them."
    )


def rerun_section(videos: Sequence[Mapping[str, Any]]) -> None:
    """Rerun one stage of one video (and what depends on it) through Prefect, and follow the
    runs started from this page."""
    from flows.serve import pipeline_parameters, served_api

    st.subheader("Rerun a stage")
    root = data_root(sys.argv[1:])
    served = served_api(root)
    labels = video_labels(videos)
    left, middle, right = st.columns([3, 2, 1], vertical_alignment="bottom")
    video = left.selectbox("Video", list(labels), format_func=labels.get, key="rerun_video")
    stage = middle.selectbox("Stage", PIPELINE_STAGES, key="rerun_stage")
    pressed = right.button(
        "Rerun",
        disabled=served is None,
        help="Recompute this stage, cached or not, then the stages after it.",
    )
    if served is None:
        st.info(
            "Reruns are Prefect runs of the pipeline's deployment: start `ringside serve` on "
            "this data directory, then reload. (`ringside rerun STAGE --video ID` reruns from a "
            "terminal.)"
        )
    else:
        st.caption(f"Runs go to Prefect at {served.removesuffix('/api')}.")
    if pressed:
        follow_run(root, video, stage, lambda: pipeline_parameters(root, video, rerun=[stage]))
    reruns = st.session_state.get("reruns", [])
    if reruns:
        # Read again every 2 s while a run is unfinished, and not at all after: a timer left
        # running would redraw whatever page the analyst has moved on to.
        pending = any(not r.get("finished") for r in reruns)
        st.fragment(rerun_progress, run_every=2.0 if pending else None)(root, labels)


def follow_run(root: Path, video: str, stage: str, parameters: Callable[[], dict]) -> bool:
    """Submit a pipeline run of ``video`` with ``parameters()`` to the served deployment and
    remember it for `rerun_progress`; False (after saying why) if Prefect refused it."""
    from flows.serve import submit_run

    started = utcnow()
    try:
        run_id = submit_run(root, parameters())
    except BadInput as error:
        st.error(f"Could not start the run: {error}")
        return False
    st.session_state.setdefault("reruns", []).append(
        {"flow_run": run_id, "video_id": video, "stage": stage, "started": started}
    )
    return True


def rerun_progress(root: Path, labels: Mapping[str, str]) -> None:
    """The state of each rerun started here: Prefect's state of the flow run and the stages it
    has finished so far. Redraws the whole page once the last of them has finished."""
    from flows.serve import run_progress

    reruns = st.session_state["reruns"]
    events = read(
        lambda con: {
            r["flow_run"]: queries.stages_finished_since(con, r["video_id"], r["started"])
            for r in reruns
        }
    )
    if events is None:
        return
    was_pending = any(not r.get("finished") for r in reruns)
    for rerun in reversed(reruns):
        progress = run_progress(root, rerun["flow_run"])
        rerun["finished"] = progress.finished
        finished = events[rerun["flow_run"]]
        share = 1.0 if progress.finished else len(finished) / len(PIPELINE_STAGES)
        what = f"{rerun['stage']} of {labels.get(rerun['video_id'], rerun['video_id'][:12])}"
        st.progress(
            share,
            text=f"Rerun of {what}: **{progress.state}**, stages finished: "
            f"{', '.join(finished) or 'none yet'}",
        )
        if progress.finished and not progress.succeeded:
            st.error(f"Rerun of {what} failed: {progress.message}")
    if was_pending and all(r["finished"] for r in reruns):
        st.rerun()


def stage_page() -> None:
    st.title("Stages")
    stage = choose("Stage", queries.METRIC_STAGES, "stage")
    found = read(
        lambda con: (
            queries.stage_metrics(con, stage),
            queries.videos(con),
            queries.datasets(con),
        )
    )
    if found is None:
        return
    rows, videos, sets = found
    if stage == "dataset" and sets:
        st.subheader("Assembled datasets")
        shown = pd.DataFrame(sets)
        shown["created_at"] = shown["created_at"].map(lambda t: f"{t:%Y-%m-%d %H:%M:%S}")
        st.table(shown, hide_index=True)
    if not rows:
        hint = HINTS.get(stage, PROCESS_HINT)
        st.info(f"No {stage} output yet: {hint}.")
        finish_page()
        return
    table = queries.metrics_table(rows)
    table = table.rename(columns=output_labels(stage, list(table.columns), videos, sets))
    st.subheader(f"Metric to compare across {COMPARED.get(stage, 'videos')}")
    metric = choose("Metric", list(table.index), "metric", label_visibility="collapsed")
    bars = pd.DataFrame({"output": table.columns, "value": table.loc[metric].to_numpy()})
    chart = (
        alt.Chart(bars)
        .mark_bar()
        .encode(
            y=alt.Y("output:N", title=None, sort=None, axis=alt.Axis(labelLimit=400)),
            x=alt.X("value:Q", title=metric, axis=alt.Axis(format=AXIS_FORMAT)),
            tooltip=["output", "value"],
        )
    )
    st.altair_chart(chart, width="stretch")
    st.subheader(f"Every {stage} metric of each newest output")
    st.caption("The numbers `ringside metrics --stage " + stage + "` prints.")
    st.table(numbers_table(table))
    against_previous_section(stage, list(dict.fromkeys(r["video_id"] for r in rows)), table)
    finish_page()


def against_previous_section(stage: str, outputs: Sequence[str], table: pd.DataFrame) -> None:
    """One video's (dataset's, run's) newest output of ``stage`` against its previous one."""
    st.subheader("Against the previous output")
    labels = dict(zip(outputs, table.columns, strict=True))
    chosen = choose("Of", list(outputs), "of", format_func=labels.get)
    history = read(lambda con: queries.outputs(con, stage, chosen))
    if history is None:
        return
    compared = queries.against_previous(history)
    if compared.empty:
        st.info(
            f"{labels[chosen]} has one {stage} output so far; change a {stage} setting and "
            "rerun to compare."
        )
        return
    newest, previous = history[0], history[1]
    st.caption(
        f"Newest: key {queries.short(newest['key'])} ({newest['created_at']:%Y-%m-%d %H:%M}); "
        f"previous: key {queries.short(previous['key'])} "
        f"({previous['created_at']:%Y-%m-%d %H:%M})."
    )
    st.table(numbers_table(compared))


def grouped_bars(frame: pd.DataFrame, title: str) -> alt.Chart:
    """Bars of ``frame`` (one row per category, one column per fighter) side by side."""
    long = frame.rename_axis("category").reset_index().melt("category", var_name="fighter")
    return (
        alt.Chart(long, title=title)
        .mark_bar()
        .encode(
            x=alt.X("category:N", title=None, sort=list(frame.index), axis=alt.Axis(labelAngle=0)),
            xOffset="fighter:N",
            y=alt.Y("value:Q", title="per minute"),
            color=alt.Color("fighter:N", scale=FIGHTER_COLOURS),
            tooltip=["fighter", "category", "value"],
        )
    )


def histogram(samples: Mapping[str, Any], name: str) -> alt.Chart:
    """Each fighter's distribution ``name`` (see `DISTRIBUTIONS`), overlaid."""
    long = pd.DataFrame(
        [(role, float(v)) for role, values in samples.items() for v in values],
        columns=["fighter", name],
    )
    return (
        alt.Chart(long, title=HISTOGRAMS[name])
        .mark_bar(opacity=0.55)
        .encode(
            x=alt.X(f"{name}:Q", bin=alt.Bin(maxbins=30), title=None),
            y=alt.Y("count():Q", stack=None, title="count"),
            color=alt.Color("fighter:N", scale=FIGHTER_COLOURS),
            tooltip=[alt.Tooltip("count():Q", title="count")],
        )
    )


def dataset_page() -> None:
    st.title("Dataset")
    sets = read_rows(
        queries.datasets,
        f"No dataset yet: {PROCESS_HINT}; the dataset stage assembles one per adversary.",
    )
    if sets is None:
        return
    labels = dataset_labels(sets)
    about = {d["dataset_key"]: d for d in sets}
    key = choose("Dataset", [d["dataset_key"] for d in sets], "dataset", format_func=labels.get)
    chosen = about[key]
    found = read(lambda con: (queries.dataset_statistics(con, key), queries.videos(con)))
    if found is None:
        return
    stats, videos = found
    st.caption(
        f"Adversary **{chosen['adversary']}**: {plural(chosen['videos'], 'video')}, "
        f"{chosen['transitions']} transitions. Statistics over all its videos, rates and "
        "per-frame means weighted by each video's minutes."
    )
    if "adversary" not in stats.combined:
        st.info("This dataset holds no statistics of the adversary (no clip of them long enough).")
        finish_page()
        return
    fighters = {role: s.scalars for role, s in stats.combined.items()}
    adversary = fighters["adversary"]
    for column, (name, label) in zip(st.columns(len(HEADLINES)), HEADLINES.items(), strict=True):
        column.metric(label, format_value(adversary.get(name)), help=SCALARS[name])
    st.caption(sample_size(adversary))

    per_minute = pd.DataFrame(fighters).reindex([f"punches_per_min_{c}" for c in (*HANDS, *KINDS)])
    per_minute.index = [name.removeprefix("punches_per_min_") for name in per_minute.index]
    left, right = st.columns(2)
    left.altair_chart(grouped_bars(per_minute.loc[list(HANDS)], "Punches per minute by hand"))
    right.altair_chart(grouped_bars(per_minute.loc[list(KINDS)], "Punches per minute by kind"))

    spread = [
        name
        for name in DISTRIBUTIONS
        if any(len(s.distributions[name]) for s in stats.combined.values())
    ]
    for column, name in zip(st.columns(2) * len(spread), spread, strict=False):
        samples = {role: s.distributions[name] for role, s in stats.combined.items()}
        if name in SAME_FOR_BOTH:
            samples = {"adversary": samples["adversary"]}
        column.altair_chart(histogram(samples, name))

    st.subheader("Every statistic")
    table = pd.DataFrame(fighters).reindex(
        [n for n in SCALARS if any(n in f for f in fighters.values())]
    )
    table.insert(0, "meaning", [SCALARS[n] for n in table.index])
    st.table(numbers_table(table))

    st.subheader("The adversary in each video")
    mine = stats.per_video[stats.per_video["role"] == "adversary"]
    per_video = mine.pivot(index="name", columns="video_id", values="value")
    per_video = per_video.rename(columns=video_labels(videos))
    st.table(numbers_table(per_video.reindex([n for n in SCALARS if n in per_video.index])))
    finish_page()


def training_page() -> None:
    st.title("Training")
    runs = read_rows(queries.training_runs, f"No training run yet: {TRAIN_HINT}.")
    if runs is None:
        return
    st.subheader("Runs")
    st.table(
        pd.DataFrame(
            {
                "run": [queries.short(r["key"]) for r in runs],
                "dataset": [queries.short(r["dataset_key"]) for r in runs],
                "adversary": [r["adversary"] or "" for r in runs],
                "iterations": [r["iterations"] for r in runs],
                "last saved": [
                    f"{r['saved_at']:%Y-%m-%d %H:%M:%S}" if r["saved_at"] else "" for r in runs
                ],
                "state": [r["state"] for r in runs],
            }
        ),
        hide_index=True,
    )
    about = {r["key"]: r for r in runs}
    key = choose("Run", list(about), "run", format_func=queries.short)
    run = about[key]
    every = st.number_input(
        "Iterations per point",
        min_value=1,
        value=queries.default_every(run["iterations"]),
        help="Each point is the mean over this many iterations.",
    )
    rows = read(lambda con: queries.curves(con, key, every=int(every)))
    if rows is None:
        return
    frame = queries.curves_frame(rows)
    last = rows[-1]
    st.subheader(f"Newest point: means over iterations {last['iterations']}")
    for column, (name, label) in zip(st.columns(len(TILES)), TILES.items(), strict=True):
        column.metric(label, format_value(last.get(name)))
    for column, (title, names) in zip(st.columns(2) * 2, CURVE_CHARTS.items(), strict=True):
        column.altair_chart(curve_chart(frame, title, names))
    finish_page()


def pose_page() -> None:
    st.title("Pose")
    found = video_review("pose", queries.pose_review)
    if found is None:
        return
    video, review = found
    st.caption(f"Pose output {queries.short(review.key)}.")
    show_video(review.overlay, "Both fighters' keypoints and tracks over the footage.")
    if review.stills:
        columns = st.columns(min(4, len(review.stills)))
        for column, (frame, name) in zip(columns * len(review.stills), review.stills, strict=False):
            path = artifact_file(name)
            if path is not None:
                column.image(str(path), caption=f"frame {frame}")

    st.subheader("Tracks")
    st.altair_chart(track_timeline(review), width="stretch")
    st.caption(
        f"Each bar is a track, from its first to its last frame, coloured by its role. "
        f"{plural(len(review.cuts), 'shot cut')} (grey rules); "
        f"{plural(len(review.handovers), 'handover')} (black ticks): frames where a fighter's "
        "keypoints come from another track than the frame before."
    )
    pick_section(video, review)

    st.subheader("Confidence per joint")
    st.altair_chart(confidence_chart(review.confidence), width="stretch")
    st.caption("The pose estimator's mean confidence over the frames each fighter was tracked.")
    finish_page()


def track_timeline(review: queries.PoseReview) -> alt.LayerChart:
    tracks = review.tracks.assign(label=[f"track {t}" for t in review.tracks["track"]])
    order = list(tracks["label"])
    bars = (
        alt.Chart(tracks)
        .mark_bar(height=12)
        .encode(
            y=alt.Y("label:N", sort=order, title=None),
            x=alt.X("first_frame:Q", title="frame"),
            x2="last_frame:Q",
            color=alt.Color("role:N", scale=ROLE_COLOURS),
            tooltip=["track", "role", "shot", "first_frame", "last_frame", "frames_observed"],
        )
    )
    cuts = (
        alt.Chart(pd.DataFrame({"frame": review.cuts}))
        .mark_rule(color="#999999", strokeDash=[4, 3])
        .encode(x="frame:Q", tooltip=["frame"])
    )
    handovers = review.handovers.assign(label=[f"track {t}" for t in review.handovers["to_track"]])
    ticks = (
        alt.Chart(handovers)
        .mark_tick(color="black", thickness=2)
        .encode(
            x="frame:Q",
            y=alt.Y("label:N", sort=order),
            tooltip=["frame", "role", "from_track", "to_track"],
        )
    )
    # Empty layers are left out: Vega-Lite cannot type the columns of an empty frame.
    layers = [bars, *([cuts] if review.cuts else []), *([ticks] if len(handovers) else [])]
    return alt.layer(*layers)


def confidence_chart(confidence: pd.DataFrame) -> alt.Chart:
    return (
        alt.Chart(confidence)
        .mark_bar()
        .encode(
            x=alt.X("joint:N", sort=None, title=None, axis=alt.Axis(labelAngle=-60)),
            xOffset="role:N",
            y=alt.Y("confidence:Q", scale=alt.Scale(domain=[0, 1])),
            color=alt.Color("role:N", scale=ROLE_COLOURS),
            tooltip=["role", "joint", alt.Tooltip("confidence:Q", format=".3f")],
        )
    )


def pick_section(video: str, review: queries.PoseReview) -> None:
    """Choose which track is the adversary: stored as the video's pick, then the pipeline
    reruns the pose stage and what depends on it through Prefect."""
    from flows.serve import pipeline_parameters, served_api

    st.subheader("Which track is the adversary?")
    root = data_root(sys.argv[1:])
    tracks = list(review.tracks["track"])
    roles = dict(zip(review.tracks["track"], review.tracks["role"], strict=True))
    current = next((t for t in tracks if roles[t] == "adversary"), tracks[0] if tracks else None)
    if current is None:
        st.info("This pose output has no tracks.")
        return
    left, right = st.columns([3, 1], vertical_alignment="bottom")
    track = left.selectbox(
        "Adversary track",
        tracks,
        index=tracks.index(current),
        format_func=lambda t: f"track {t} (now {roles[t]})",
    )
    served = served_api(root)
    if right.button("Pick and rerun", disabled=served is None or track == current):
        with connect(data_paths(root).db, wait_s=LOCK_WAIT_S) as con:
            record_pick(con, video, int(track))
        if follow_run(root, video, "pose", lambda: pipeline_parameters(root, video, rerun=None)):
            st.success(f"Track {track} is the adversary now; the Overview page follows the rerun.")
    picked = "no pick yet" if review.pick is None else f"track {review.pick}"
    hint = "" if served is not None else " Start `ringside serve` to pick from here."
    st.caption(f"The analyst's pick for this video: {picked}.{hint}")


def sample_size(scalars: Mapping[str, float]) -> str:
    """What the rates above were measured on: the footage's length and the events counted
    (a rate is a count over the minutes, so the count is the rate times the minutes)."""
    minutes = scalars.get("minutes") or 0.0
    counts = {
        what: round((scalars.get(rate) or 0.0) * minutes)
        for what, rate in (("punch", "punches_per_min"), ("step", "steps_per_min"))
    }
    few = (
        " A rate from a handful of events is a rough estimate." if min(counts.values()) < 10 else ""
    )
    punches = plural(counts["punch"], "punch", "punches")
    return (
        f"Measured on {minutes * 60:.1f} s of the adversary's footage: {punches} and "
        f"{plural(counts['step'], 'step')} labelled.{few}"
    )


def lift_page() -> None:
    st.title("Lift")
    found = video_review("lift", queries.lift_review)
    if found is None:
        return
    _, review = found
    st.caption(
        f"Lift output {queries.short(review.key)}. The numbers summarise the "
        f"{review.seconds:.1f} s of "
        "30 Hz series charted below, both fighters together; the stage's own summaries, in the "
        "table at the bottom, are measured at the video's frame rate before resampling."
    )
    tiles = review.tiles
    for column, (label, value) in zip(st.columns(len(tiles)), tiles.items(), strict=True):
        column.metric(label, format_value(value))
    show_video(
        review.video,
        "Both humanoids in MuJoCo, after the physics cleanup (adversary red, opponent blue).",
    )
    st.subheader("Cleanup over time")
    long = (
        review.series.reset_index()
        .melt("time_s", var_name="curve")
        .assign(
            measure=lambda f: f["curve"].str.split("|").str[0],
            fighter=lambda f: f["curve"].str.split("|").str[1],
        )
    )
    measures = list(dict.fromkeys(long["measure"]))
    for column, measure in zip(st.columns(2) * len(measures), measures, strict=False):
        column.altair_chart(series_chart(long[long["measure"] == measure], measure))
    st.caption(
        "Foot skating: horizontal speed of the faster foot in contact with the floor. "
        "Floor penetration: depth of the deepest body part below the floor. Distance: pelvis "
        "to pelvis, horizontally. Gaps are steps where a fighter was not lifted."
    )
    st.subheader("Every lift metric")
    st.table(numbers_table(pd.DataFrame({"value": review.metrics})))
    finish_page()


def series_chart(long: pd.DataFrame, title: str) -> alt.Chart:
    """One cleanup measure over time, a line per fighter."""
    return (
        alt.Chart(long, title=title)
        .mark_line()
        .encode(
            x=alt.X("time_s:Q", title="seconds"),
            y=alt.Y("value:Q", title=None, axis=alt.Axis(format=AXIS_FORMAT)),
            color=alt.Color(
                "fighter:N",
                scale=alt.Scale(
                    domain=["adversary", "opponent", "both"],
                    range=["#c8102e", "#1f5fbf", "#555555"],
                ),
            ),
            tooltip=["fighter", "time_s", "value"],
        )
    )


def evaluation_page() -> None:
    st.title("Evaluation")
    runs = read_rows(queries.evaluations, f"No evaluation yet: {HINTS['evaluate']}.")
    if runs is None:
        return
    about = {r["run_key"]: r for r in runs}
    run_key = choose("Run", list(about), "run", format_func=queries.short)
    chosen = about[run_key]
    tables = read(lambda con: queries.evaluation(con, chosen["key"], run_key))
    if tables is None:
        return
    metrics = chosen["metrics"]
    st.caption(
        f"Evaluation {queries.short(chosen['key'])} of training run {queries.short(run_key)}."
    )
    tiles = EVALUATION_TILES
    for column, (name, label) in zip(st.columns(len(tiles)), tiles.items(), strict=True):
        column.metric(label, format_value(metrics.get(name)))
    st.caption(
        "Style scores: distance to the adversary's real statistics, 0-1, lower is closer. Bouts "
        "ended by a fall: episodes that a fall of either fighter ended, per simulated minute (as "
        "training counts them); the Boxing table counts each fighter's own falls."
    )
    bout = next((r["artifact"] for r in tables["artifacts"] if r["name"] == "bout.mp4"), None)
    show_video(bout, "The trained fighters' bout, rendered in MuJoCo.")
    st.subheader("Style, per statistic")
    style = pd.DataFrame(tables["style"])
    if not style.empty:
        st.table(numbers_table(style.pivot(index="statistic", columns="policy", values="distance")))
    st.subheader("Boxing")
    boxing = pd.DataFrame(tables["boxing"])
    if not boxing.empty:
        st.table(numbers_table(boxing.pivot(index="metric", columns="policy", values="value")))
    st.subheader("Damage per episode, N (MAAIP Table 1)")
    st.table(numbers_table(pd.DataFrame(tables["damage"])), hide_index=True)
    st.subheader("Normalised heading return (MAAIP Table 2)")
    if tables["heading"]:
        st.table(numbers_table(pd.DataFrame(tables["heading"])), hide_index=True)
    else:
        st.info(
            "No heading run on this dataset yet (train with `--train-reward-control-task heading`)."
        )
    finish_page()


def curve_chart(frame: pd.DataFrame, title: str, names: Mapping[str, str]) -> alt.Chart:
    """The curves ``names`` (column -> legend label) of ``frame`` against the iteration."""
    present = {name: label for name, label in names.items() if name in frame.columns}
    long = (
        frame[list(present)]
        .rename(columns=present)
        .reset_index()
        .melt("iteration", var_name="curve")
    )
    return (
        alt.Chart(long, title=title)
        .mark_line(point=len(frame) < 30)
        .encode(
            x=alt.X("iteration:Q", axis=alt.Axis(format="d", tickMinStep=1)),
            y=alt.Y("value:Q", title=None, axis=alt.Axis(format=AXIS_FORMAT)),
            color=alt.Color(
                "curve:N",
                sort=list(present.values()),
                legend=alt.Legend(orient="bottom", title=None, labelLimit=400),
            ),
            tooltip=["curve", "iteration", "value"],
        )
    )


# URL path -> (title, page), in the sidebar's order; the first is the home page.
PAGES: dict[str, tuple[str, Callable[[], None]]] = {
    "overview": ("Overview", overview_page),
    "stages": ("Stages", stage_page),
    "pose": ("Pose", pose_page),
    "lift": ("Lift", lift_page),
    "dataset": ("Dataset", dataset_page),
    "training": ("Training", training_page),
    "evaluation": ("Evaluation", evaluation_page),
}


def main() -> None:
    st.set_page_config(page_title="Ringside", layout="wide")
    home = next(iter(PAGES))
    page = st.navigation(
        [
            st.Page(draw, title=title, url_path=path, default=path == home)
            for path, (title, draw) in PAGES.items()
        ]
    )
    st.sidebar.caption(f"Data: `{data_root(sys.argv[1:])}`")
    # Pages read the database on each render; the button is one without touching a widget.
    st.sidebar.button("Reload", help="Read the database again")
    page.run()


if __name__ == "__main__":
    main()
