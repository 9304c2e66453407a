"""The Stages page: one stage's metrics across videos (or datasets, or training runs), and
against the previous output."""

from __future__ import annotations

from collections.abc import Sequence

import altair as alt
import pandas as pd
import streamlit as st

from dashboards import queries
from dashboards.widgets import (
    AXIS_FORMAT,
    HINTS,
    PROCESS_HINT,
    choose,
    finish_page,
    numbers_table,
    output_labels,
    read,
)
from tasks import registry
from tasks.registry import Subject

# What the Stages page compares, for the stages whose outputs are not per video.
COMPARED = {Subject.DATASET: "datasets", Subject.RUN: "training runs"}


def stage_page() -> None:
    st.title("Stages")
    stage = choose("Stage", queries.metric_stages(), "stage")
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
    compared = COMPARED.get(registry.stage(stage).subject, "videos")
    st.subheader(f"Metric to compare across {compared}")
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
