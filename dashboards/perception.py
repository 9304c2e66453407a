"""The Pose and Lift pages: one video's tracks, confidence, overlay and the analyst's pick of
the adversary; its lifted motion, cleanup series and review video."""

from __future__ import annotations

import altair as alt
import pandas as pd
import streamlit as st

from dashboards import queries
from dashboards.widgets import (
    AXIS_FORMAT,
    LOCK_WAIT_S,
    ROLE_COLOURS,
    artifact_file,
    data,
    finish_page,
    follow_run,
    format_value,
    numbers_table,
    plural,
    show_video,
    video_review,
)
from storage.db import connect
from tasks.pose.store import record_pick


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
    from flows.launch import pipeline_parameters, served_api

    st.subheader("Which track is the adversary?")
    paths = data()
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
    served = served_api(paths)
    if right.button("Pick and rerun", disabled=served is None or track == current):
        with connect(paths.db, wait_s=LOCK_WAIT_S) as con:
            record_pick(con, video, int(track))
        if follow_run(paths, video, "pose", lambda: pipeline_parameters(paths, video, rerun=None)):
            st.success(f"Track {track} is the adversary now; the Overview page follows the rerun.")
    picked = "no pick yet" if review.pick is None else f"track {review.pick}"
    hint = "" if served is not None else " Start `ringside serve` to pick from here."
    st.caption(f"The analyst's pick for this video: {picked}.{hint}")


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
