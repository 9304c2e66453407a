"""The Dataset, Training and Evaluation pages: the adversary's statistics, the learning
curves, and the trained opponent judged."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import altair as alt
import pandas as pd
import streamlit as st

from dashboards import queries
from dashboards.widgets import (
    AXIS_FORMAT,
    FIGHTER_COLOURS,
    HINTS,
    PROCESS_HINT,
    TRAIN_HINT,
    choose,
    dataset_labels,
    finish_page,
    format_value,
    numbers_table,
    plural,
    read,
    read_rows,
    show_video,
    video_labels,
)
from tasks.dataset.labels import HANDS, KINDS
from tasks.dataset.statistics import DISTRIBUTIONS, SCALARS

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

# The Training page's headline numbers: the newest block's means of these.
TILES = {
    "episode_length_s": "Episode length (s)",
    "reward_motion": "Motion reward",
    "reward_interaction": "Interaction reward",
    "falls_per_min": "Falls per minute",
}
# A tracker's (train.objective 'track'): it has no discriminators.
TRACK_TILES = {
    "episode_length_s": "Episode length (s)",
    "reward_total": "Tracking reward",
    "body_error_cm": "Body error (cm)",
    "root_error_cm": "Root error (cm)",
}
TRACK_CHARTS: dict[str, dict[str, str]] = {
    "Episode length (s)": {"episode_length_s": "episode length"},
    "Tracking reward (DeepMimic's)": {"reward_total": "total"},
    "Falls per minute": {"falls_per_min": "falls per minute"},
    "Tracking error (cm)": {"body_error_cm": "bodies", "root_error_cm": "root"},
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
    found = read(
        lambda con: (
            queries.dataset_statistics(con, key),
            queries.videos(con),
            queries.dataset_tracking(con, key),
        )
    )
    if found is None:
        return
    stats, videos, (tracker, tracked) = found
    if chosen["unusable"] is not None:
        st.error(f"Unusable for training: {chosen['unusable']}")
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
    tracking_section(tracker, tracked)
    finish_page()


def tracking_section(tracker: str, tracked: list[dict]) -> None:
    """Each clip's tracking error: how well a physics body follows that footage."""
    st.subheader("Can a physics body follow each clip?")
    if not tracked:
        st.info(
            "No tracker has been trained on this dataset: `ringside train --dataset KEY "
            "--train-objective track` trains one and tracks every clip."
        )
        return
    st.caption(
        f"Tracker run {tracker[:12]} followed each clip from its first frame (agent 0 the "
        "adversary, 1 the opponent): a clip it could not finish, or followed with a large body "
        "error, is footage the physics cannot reproduce. Held-out clips (validation) first, "
        "then by body error, worst first."
    )
    st.table(numbers_table(pd.DataFrame(tracked).set_index(["split", "agent", "clip"])))


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
    tracker = "body_error_cm" in last
    tiles, charts = (TRACK_TILES, TRACK_CHARTS) if tracker else (TILES, CURVE_CHARTS)
    if tracker:
        st.caption("A tracker: it follows the dataset's clips; its rewards are DeepMimic's.")
    for column, (name, label) in zip(st.columns(len(tiles)), tiles.items(), strict=True):
        column.metric(label, format_value(last.get(name)))
    for column, (title, names) in zip(st.columns(2) * 2, charts.items(), strict=True):
        column.altair_chart(curve_chart(frame, title, names))
    if tracker:
        gate_section(read(lambda con: queries.gate_checks(con, key)) or [])
    finish_page()


def gate_section(checks: list[dict[str, Any]]) -> None:
    """A tracker's gate checks: held or not, and the last few."""
    st.subheader("The gate")
    if not checks:
        st.info(
            "No gate check yet: the train stage gates a tracker every `train.track.gate_every` "
            "iterations."
        )
        return
    last = checks[-1]
    held = [c["iterations"] for c in checks if c.get("gate_held")]
    st.caption(
        "Every clip of the train split tracked from its first frame on the policy's mean. Held "
        "when met in `train.track.gate_needed` of the last `gate_window` checks (3 of 5 unless "
        "set): "
        + (
            f"**held** from the check after {held[0]} iterations on."
            if held
            else f"**not held** after {last['iterations']} iterations."
        )
    )
    table = pd.DataFrame(checks[-10:]).set_index("iterations")
    table = table.rename(
        columns={
            "gate_finished_pct": "clips finished (%)",
            "gate_body_error_cm": "body error (cm)",
            "gate_root_error_cm": "root error (cm)",
            "gate_met": "met",
            "gate_held": "held",
        }
    )
    for flag in ("met", "held"):
        if flag in table:
            table[flag] = table[flag].map({1.0: "yes", 0.0: "no"})
    st.table(numbers_table(table))


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
    st.subheader("Moves like its footage? Held-out classifier test")
    st.caption(
        "A fresh classifier tells 1-second windows of the adversary's held-out footage from a "
        "simulated fighter's; its AUC on windows it never trained on, with a bootstrap 95 % "
        "interval: 0.5, it cannot tell them apart; 1, it always can. Reference 'replay' is "
        "the tracker replaying that footage (its physically valid version); policy 'train' is "
        "the reference's own train split, the level a perfect answer reaches. The feature gap: "
        "the window features' mean difference in the reference's standard deviations."
    )
    classifier = pd.DataFrame(tables["classifier"])
    if not classifier.empty:
        st.table(numbers_table(classifier.set_index(["reference", "policy"])))
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
