"""The Overview page: every video's stages, the opponent, and reruns started from the page."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import pandas as pd
import streamlit as st

from dashboards import queries
from dashboards.widgets import (
    PROCESS_HINT,
    data,
    finish_page,
    follow_run,
    format_value,
    read,
    video_labels,
)
from storage.paths import DataPaths
from tasks import registry
from tasks.registry import Subject, names, per_video

# How a stage's subject is named in the opponent table.
SUBJECT_NAMES = {Subject.DATASET: "dataset", Subject.RUN: "run"}

STATE_COLOURS = {
    "done": "#d4f0da",
    "cached": "#dde9fa",
    "failed": "#f8d3d2",
    "running": "#fff3c4",
    "interrupted": "#fbe0c4",
    "missing": "#eeeeee",
}


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
        matrix.style.map(
            lambda s: f"background-color: {STATE_COLOURS.get(s, '')}", list(per_video())
        )
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
    of = [
        f"{SUBJECT_NAMES[registry.stage(r['stage']).subject]} {queries.short(r['video_id'])}"
        for r in rows
    ]
    table = pd.DataFrame(
        {
            "adversary": [r["adversary"] for r in rows],
            "stage": [r["stage"] for r in rows],
            "of": of,
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
    from flows.launch import pipeline_parameters, served_api

    st.subheader("Rerun a stage")
    paths = data()
    served = served_api(paths)
    labels = video_labels(videos)
    left, middle, right = st.columns([3, 2, 1], vertical_alignment="bottom")
    video = left.selectbox("Video", list(labels), format_func=labels.get, key="rerun_video")
    stage = middle.selectbox("Stage", names(), key="rerun_stage")
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
        follow_run(paths, video, stage, lambda: pipeline_parameters(paths, video, rerun=[stage]))
    reruns = st.session_state.get("reruns", [])
    if reruns:
        # Read again every 2 s while a run is unfinished, and not at all after: a timer left
        # running would redraw whatever page the analyst has moved on to.
        pending = any(not r.get("finished") for r in reruns)
        st.fragment(rerun_progress, run_every=2.0 if pending else None)(paths, labels)


def rerun_progress(paths: DataPaths, labels: Mapping[str, str]) -> None:
    """The state of each rerun started here: Prefect's state of the flow run and the stages it
    has finished so far. Redraws the whole page once the last of them has finished."""
    from flows.launch import run_progress

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
        progress = run_progress(paths, rerun["flow_run"])
        rerun["finished"] = progress.finished
        finished = events[rerun["flow_run"]]
        share = 1.0 if progress.finished else len(finished) / len(names())
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
