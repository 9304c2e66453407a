"""What commands print: tables, run summaries, the opponent, damage found."""

from __future__ import annotations

import dataclasses
import json
from typing import Any

from storage.paths import DataPaths


def print_table(rows: list[dict[str, Any]], columns: list[str]) -> None:
    if not rows:
        print("(nothing yet)")
        return
    text = [[("" if r[c] is None else str(r[c])) for c in columns] for r in rows]
    widths = [max(len(c), *(len(t[i]) for t in text)) for i, c in enumerate(columns)]
    print("  ".join(c.ljust(w) for c, w in zip(columns, widths, strict=True)))
    for t in text:
        print("  ".join(v.ljust(w) for v, w in zip(t, widths, strict=True)))


def print_summary(summaries: list, paths: DataPaths, as_json: bool) -> None:

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
    print_table(shown, ["video_id", "stage", "state", "key", "seconds", "path"])
    for row in rows:
        where = " ".join(filter(None, (row["stage"], row["video_id"][:12])))
        for note in row["notes"]:
            print(f"note: {where}: {note}")
    print(f"\nresults: {paths.db}\nartifacts: {paths.artifacts}")
    print("see them with: ringside status | ringside metrics")


# The two-sample test's fighters, as the lines below name them.
CLASSIFIED = {
    "adversary": "trained",
    "untrained": "untrained",
    "still": "standing still",
    "matched": "matched opponent",
    "replay": "tracker replaying the footage",
    "train": "its own train split (real against real)",
}


def classifier_lines(rows: list[dict], metrics: dict[str, float]) -> list[str]:
    """The held-out two-sample test in a line per reference: each fighter's AUC and its 95 %
    interval against the held-out footage (or why it was not measured), then against the
    tracker's replay of it, each beside the reference's own train split; then the feature gap;
    and the share of the still-to-replay gap the adversary closes on each figure, when
    measured."""
    head = "moves like its footage? held-out classifier AUC, 0.5 = indistinguishable, 1 = always"
    lines = []
    for reference, intro in (("footage", f"{head} told apart"), ("replay", "  against the replay")):
        found = {r["policy"]: r for r in rows if r.get("reference", "footage") == reference}
        measured = [p for p in CLASSIFIED if p in found and found[p]["auc"] is not None]
        if not measured:
            reason = next((r["reason"] for r in found.values() if r["reason"]), "no rows")
            lines.append(f"{intro}: not measured ({reason})")
            continue
        parts = [
            f"{CLASSIFIED[p]} {found[p]['auc']:.2f} [{found[p]['auc_low']:.2f}, "
            f"{found[p]['auc_high']:.2f}]"
            for p in measured
        ]
        line = f"{intro}: {', '.join(parts)}"
        if reference == "footage" and "replay" not in measured and "replay" in found:
            line += f"; no replay ({found['replay']['reason']})"
        if reference == "footage":
            line += _closed(metrics, "two_sample_gap_closed", "of the still-to-replay gap")
        lines.append(line)
        if reference == "footage":
            gaps = ", ".join(f"{CLASSIFIED[p]} {found[p]['feature_gap']:.2f}" for p in measured)
            line = f"  feature gap, mean |difference| in the footage's SDs, 0 = alike: {gaps}"
            lines.append(line + _closed(metrics, "feature_gap_closed", "of the gap"))
    return lines


def _closed(metrics: dict[str, float], name: str, what: str) -> str:
    """The shares of the still-to-replay gap the trained adversary and the matched opponent
    close (metric ``name``, suffixed), as a clause; empty when neither was measured."""
    said = [
        f"the {who} closes {100 * metrics[name + suffix]:.0f} % {what}"
        for who, suffix in (("trained adversary", ""), ("matched opponent", "_matched"))
        if name + suffix in metrics
    ]
    return "; " + ", ".join(said) if said else ""


def print_opponent(paths: DataPaths, evaluated) -> None:
    """Where the pipeline's opponent is (the folder its evaluation exported, written where
    `ringside export` writes it), its bout and its headline numbers against the evaluation's
    baselines."""
    from storage.artifacts import artifact_path
    from storage.db import connect
    from storage.records import output_metrics
    from tasks.evaluate.store import evaluation_artifacts, evaluation_tables
    from tasks.opponent.export import stored_opponent
    from tasks.opponent.folder import MANIFEST

    run_key = evaluated.video_id
    with connect(paths.db, read_only=True) as con:
        metrics = output_metrics(con, "evaluate", run_key, evaluated.key)
        media = evaluation_artifacts(con, evaluated.key, run_key)
        tables = evaluation_tables(con, evaluated.key, run_key)
    classifier = tables["classifier"]
    steps = {r["policy"]: r["value"] for r in tables["boxing"] if r["metric"] == "steps_per_min"}
    out = paths.root / "opponents" / f"{run_key[:12]}-adversary"
    folder = stored_opponent(paths.artifacts, media, out)
    iteration = json.loads((folder / MANIFEST).read_text())["iteration"]

    def number(name: str) -> str:
        value = metrics.get(name)
        return "n/a" if value is None else f"{value:.3g}"

    print(f"\nopponent of {evaluated.path}: run {run_key[:12]} at iteration {iteration}")
    print(f"  folder: {folder}   (spar with it: ringside spar {folder})")
    if "bout.mp4" in media:
        print(f"  bout:   {artifact_path(paths.artifacts, media['bout.mp4'])}")
    print(
        f"  bouts ended by a fall, per simulated minute: {number('falls_per_min')} "
        f"(untrained {number('falls_per_min_untrained')}, "
        f"standing still in its guard {number('falls_per_min_still')}, matched opponent "
        f"{number('falls_per_min_matched')})"
    )

    def rate(policy: str) -> str:
        value = steps.get(policy)
        return "n/a" if value is None else f"{value:.3g}"

    print(
        f"  steps per simulated minute: {rate('adversary')} (standing still in its guard "
        f"{rate('still')}, matched opponent {rate('matched')}; the held-out footage "
        f"{number('footage_steps_per_min')})"
    )
    print(
        f"  style score, 0 = the footage's statistics, lower is closer: {number('style_score')} "
        f"(untrained {number('style_score_untrained')}, standing still "
        f"{number('style_score_still')})"
    )
    for line in classifier_lines(classifier, metrics):
        print(f"  {line}")
    print(f"  motion as BVH: ringside export-motion --run {run_key[:12]}")
    print(f"  all of it: ringside evaluate --run {run_key[:12]}   or   ringside dashboard")


def print_problems(problems) -> None:
    """A line per damaged output (its problems counted), then the rest one by one."""
    if not problems:
        print(
            "no damage found: every table reads back, every block of the database file matches "
            "its checksum and every file of the artifact store its name"
        )
        return
    by_output: dict = {}
    for problem in problems:
        by_output.setdefault(problem.output or problem, []).append(problem)
    for found in by_output.values():
        first = found[0]
        if first.output is None:
            print(f"{first.stage}: {first.what}")
            continue
        more = f" (and {len(found) - 1} more)" if len(found) > 1 else ""
        print(
            f"{first.stage} of {first.video_id[:12]}, output {first.key[:12]}: {first.what}{more}"
        )


def pivot(rows: list[dict], row_key: str, column_key: str, cell) -> list[dict]:
    """Long rows as one row per ``row_key`` with a column per ``column_key``, in first-seen
    order; ``cell(row)`` is what a cell shows."""
    out: dict[str, dict] = {}
    for r in rows:
        out.setdefault(r[row_key], {row_key: r[row_key]})[r[column_key]] = cell(r)
    return list(out.values())
