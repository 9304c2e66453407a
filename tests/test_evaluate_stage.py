"""The evaluate stage on a tiny training run of the demo's dataset: the CLI fills every table,
caches, reruns to the same numbers, stores a loadable opponent and a playable bout, and fails
fast on a run that does not exist; given held-out footage, its two-sample test's known answers."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import (
    TINY_EVALUATE_FLAGS,
    TINY_TRAIN_FLAGS,
    copy_data,
    query,
    read_video,
    run_cli,
)

from models.humanoid.boxer import BoneLengths
from storage.artifacts import artifact_path, read_bytes
from storage.db import connect
from storage.paths import data_paths
from tasks.dataset.store import FootageClip, footage_clips
from tasks.evaluate.metrics import RATES, SHARES, STYLE_DISTRIBUTIONS
from tasks.evaluate.stage import NO_TRACKER, POLICIES, TWO_SAMPLE_POLICIES
from tasks.opponent.folder import load_opponent

TINY_TRAIN = [*TINY_TRAIN_FLAGS, "--train-iterations", "2"]
REQUIRED = ("onnx_max_abs_diff", "style_score", "style_score_untrained", "falls_per_min")


def _evaluate(capsys, data: Path, run: str, *flags: str) -> dict:
    argv = ["--data", str(data), "evaluate", "--run", run, *TINY_EVALUATE_FLAGS, *flags, "--json"]
    code, out, err = run_cli(capsys, *argv)
    assert code == 0, err
    return json.loads(out)


@pytest.fixture(scope="module")
def run_key(sample_run, sample_dataset) -> str:
    """A tiny training run (2 iterations) on the demo's dataset."""
    from flows.cli import main

    argv = ["--data", str(sample_run), "train", "--dataset", sample_dataset, *TINY_TRAIN]
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main([*argv, "--json"]) == 0
    return json.loads(out.getvalue())[0]["key"]


def test_evaluate_fills_every_table_caches_and_reruns_identically(capsys, sample_run, run_key):
    first = _evaluate(capsys, sample_run, run_key[:10])
    summary, metrics, tables = first["summary"], first["metrics"], first["tables"]
    assert summary["stage"] == "evaluate" and summary["state"] == "done"
    assert summary["video_id"] == run_key

    for name in REQUIRED:
        assert name in metrics and math.isfinite(metrics[name]), name
    assert metrics["onnx_max_abs_diff"] < 1e-5
    for name in (
        "style_score",
        "style_score_untrained",
        "style_score_opponent",
        "style_score_still",
    ):
        assert 0.0 <= metrics[name] <= 1.0

    # Table 1: this run (imitation only) with each agent's damage.
    mine = [r for r in tables["damage"] if r["run_key"] == run_key]
    assert [(r["control_task"], r["agent"]) for r in mine] == [("none", 0), ("none", 1)]
    d0, d1 = mine
    assert d0["received_n"] == d1["dealt_n"] and d0["dealt_n"] == d1["received_n"]
    assert (d0["episodes"], d0["frames"]) == (4, 60)
    # Table 2 without a heading run on the dataset: empty, and a note says so.
    if not _finished_runs(sample_run, "heading"):
        assert tables["heading"] == []
        assert any(note.startswith("heading table: not available") for note in summary["notes"])

    statistics = {*RATES, *SHARES, *STYLE_DISTRIBUTIONS}
    # No tracker on the sample's dataset: no matched pair, in no table.
    simulated = [p for p, (bouts, _) in POLICIES.items() if bouts != "matched"]
    for table in ("style", "boxing"):
        assert {r["policy"] for r in tables[table]} <= {*simulated, "footage"}
    for policy in simulated:
        rows = [r for r in tables["style"] if r["policy"] == policy]
        assert {r["statistic"] for r in rows} == statistics
        assert all(0.0 <= r["distance"] <= 1.0 for r in rows)
        score = metrics["style_score" + ("" if policy == "adversary" else f"_{policy}")]
        assert score == pytest.approx(np.mean([r["distance"] for r in rows]))
        boxing = {r["metric"]: r["value"] for r in tables["boxing"] if r["policy"] == policy}
        for name in ("falls_per_min", "foot_skating_cm_per_frame", "time_in_guard_pct"):
            assert math.isfinite(boxing[name]), (policy, name)
    # The real values are the adversary's statistics from the dataset stage.
    real = dict(
        query(
            sample_run,
            "SELECT s.name, s.value FROM dataset_statistics s JOIN dataset_members m "
            "ON s.key = m.key AND s.video_id = m.video_id WHERE s.role = 'adversary'",
        )
    )
    for r in tables["style"]:
        if r["kind"] != "distribution":
            assert r["real"] == pytest.approx(real[r["statistic"]])

    # The two-sample test: the held-out footage against each simulated fighter, or NULL and why.
    against = {(r["reference"], r["policy"]): r for r in tables["classifier"]}
    assert sorted(against) == sorted(
        [*(("footage", p) for p in (*TWO_SAMPLE_POLICIES, "replay", "train"))]
        + [("replay", p) for p in (*TWO_SAMPLE_POLICIES, "train")]
    )
    two_sample = {p: r for (ref, p), r in against.items() if ref == "footage"}
    # No tracker on the dataset: nothing is judged against its replay.
    assert all(r["reason"] == NO_TRACKER for (ref, _), r in against.items() if ref == "replay")
    # No tracker was trained on the sample's dataset, so nothing replays its footage.
    assert two_sample["replay"]["auc"] is None and two_sample["replay"]["simulated_windows"] == 0
    heldout = query(
        sample_run,
        "SELECT sum(end_step - start_step) FROM dataset_clips WHERE kind = 'interaction' "
        "AND split = 'validation'",
    )[0][0]
    for policy in TWO_SAMPLE_POLICIES:
        row = two_sample[policy]
        if row["auc"] is None:
            assert row["reason"] and row["auc_low"] is None and row["auc_high"] is None
        else:
            assert 0.0 <= row["auc_low"] <= row["auc"] <= row["auc_high"] <= 1.0
            assert row["reason"] is None and row["real_windows"] >= 5
    if not heldout:  # the demo's footage is too short to hold any out
        assert all(two_sample[p]["auc"] is None for p in TWO_SAMPLE_POLICIES)
        assert two_sample["adversary"]["reason"].startswith("no held-out footage")
        assert two_sample["replay"]["reason"].startswith("no held-out footage")
        assert "two_sample_auc" not in metrics
        assert any(n.startswith("two-sample test: not measured") for n in summary["notes"])
    else:
        assert ("two_sample_auc" in metrics) == (two_sample["adversary"]["auc"] is not None)
        assert two_sample["replay"]["reason"] == NO_TRACKER

    # The opponent folder comes back from the artifact store and loads with onnxruntime.
    paths = data_paths(sample_run)
    stored = {r["name"]: r["artifact"] for r in tables["artifacts"]}
    folder = sample_run.parent / "opponent-from-store"
    folder.mkdir(exist_ok=True)
    for name, artifact in stored.items():
        if name.startswith("opponent/"):
            (folder / name.removeprefix("opponent/")).write_bytes(
                read_bytes(paths.artifacts, artifact)
            )
    opponent = load_opponent(folder)
    assert opponent.agent == 0 and opponent.manifest["run_key"] == run_key
    # The bout plays: up to 1 s at 30 Hz (the episodes may be shorter in all), in frames that
    # are pictures rather than one flat colour.
    _, frames = read_video(artifact_path(paths.artifacts, stored["bout.mp4"]))
    assert 1 < len(frames) == metrics["video_frames"] <= 30
    assert frames[0].shape == (360, 640, 3) and frames[0].std() > 10 and frames[-1].std() > 10

    again = _evaluate(capsys, sample_run, run_key[:10])
    assert again["summary"]["state"] == "cached" and again["summary"]["key"] == summary["key"]

    rerun = _evaluate(capsys, sample_run, run_key[:10], "--rerun")
    assert rerun["summary"]["state"] == "done"
    # Fixed seeds: the same numbers to the last bit (JSON text compares NaN with NaN too).
    assert json.dumps(rerun["tables"]) == json.dumps(tables)
    assert rerun["metrics"] == metrics

    code, out, _ = run_cli(capsys, "--data", str(sample_run), "metrics", "--stage", "evaluate")
    assert code == 0 and "style_score_untrained" in out and "onnx_max_abs_diff" in out
    code, out, _ = run_cli(
        capsys, "--data", str(sample_run), "evaluate", "--run", run_key, *TINY_EVALUATE_FLAGS
    )
    assert code == 0 and "damage per episode" in out and "style_score (lower is closer)" in out


def _finished_runs(data: Path, control_task: str) -> list[str]:
    rows = query(
        data,
        "SELECT p.key FROM train_policies p JOIN stage_outputs o ON o.stage = 'train' "
        "AND o.key = p.key WHERE json_extract_string(o.config, '$.reward.control_task') = ?",
        [control_task],
    )
    return [key for (key,) in rows]


def test_damage_and_heading_runs_join_the_tables(capsys, sample_run, run_key):
    """A damage-minimising and a heading run on the same dataset: the evaluation of the first
    run is no longer the cached one, Table 1 gains the damage_min row and Table 2 appears."""
    before = _evaluate(capsys, sample_run, run_key)["summary"]["key"]
    dataset_key = query(sample_run, "SELECT video_id FROM train_policies WHERE key = ?", [run_key])
    base = ["--data", str(sample_run), "train", "--dataset", dataset_key[0][0], *TINY_TRAIN]
    for task in ("damage_min", "heading"):
        flags = ["--train-reward-control-task", task, "--train-reward-w-control", "0.5"]
        code, _, err = run_cli(capsys, *base, *flags)
        assert code == 0, err
    heading_runs = _finished_runs(sample_run, "heading")
    damage_runs = _finished_runs(sample_run, "damage_min")
    short = ["--evaluate-heading-episodes", "2", "--evaluate-heading-frames", "30"]
    after = _evaluate(capsys, sample_run, run_key, *short)
    assert after["summary"]["state"] == "done" and after["summary"]["key"] != before
    tables = after["tables"]
    labelled = {(r["run_key"], r["control_task"]) for r in tables["damage"]}
    assert {(run_key, "none"), *((k, "damage_min") for k in damage_runs)} == labelled
    assert {(r["run_key"], r["agent"]) for r in tables["heading"]} == {
        (k, a) for k in heading_runs for a in (0, 1)
    }
    for row in tables["heading"]:
        assert row["motion_prior"] is True and (row["episodes"], row["frames"]) == (2, 30)
        assert 0.0 <= row["normalized_return"] <= 1.0
    assert not any(n.startswith("heading table") for n in after["summary"]["notes"])


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--run", "zzz"], "--run zzz: matches no finished training run"),
        (["--run", "0", "--evaluate-episodes", "0"], "evaluate.episodes must be an integer >= 1"),
    ],
)
def test_bad_evaluation_input_fails_fast(capsys, sample_run, flags, message):
    before = query(sample_run, "SELECT count(*) FROM stage_outputs WHERE stage = 'evaluate'")
    code, _, err = run_cli(capsys, "--data", str(sample_run), "evaluate", *flags)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert (
        query(sample_run, "SELECT count(*) FROM stage_outputs WHERE stage = 'evaluate'") == before
    )


def test_the_held_out_footage_is_the_validation_interaction_clips(
    sample_run, sample_dataset, tmp_path
):
    """The demo holds no footage out (its validation split is shorter than a clip); in a copy
    whose interaction clips are marked held out, `footage_clips` gives their lifted steps,
    both fighters' qpos at the same steps."""
    data = copy_data(sample_run, tmp_path / "data")
    clips = query(
        data,
        "SELECT c.video_id, json_extract_string(o.upstream, '$.lift'), c.start_step, "
        "c.end_step FROM dataset_clips c JOIN dataset_members m ON m.key = c.key "
        "AND m.video_id = c.video_id JOIN stage_outputs o ON o.stage = 'dataset' "
        "AND o.key = c.key AND o.video_id = c.video_id WHERE m.dataset_key = ? "
        "AND c.kind = 'interaction' ORDER BY c.video_id, c.clip",
        [sample_dataset],
    )
    with connect(data / "ringside.duckdb") as con:
        assert footage_clips(con, sample_dataset, split="validation") == []
        con.execute("UPDATE dataset_clips SET split = 'validation' WHERE kind = 'interaction'")
        found = footage_clips(con, sample_dataset, split="validation")
    assert [(c.video_id, len(c.qpos)) for c in found] == [(v, b - a) for v, _, a, b in clips]
    for clip, (video_id, lift_key, start, end) in zip(found, clips, strict=True):
        for role, qpos in (("adversary", clip.qpos), ("opponent", clip.other_qpos)):
            rows = query(
                data,
                "SELECT qpos FROM lift_motion WHERE key = ? AND video_id = ? AND role = ? "
                "AND step >= ? AND step < ? ORDER BY step",
                [lift_key, video_id, role, start, end],
            )
            assert np.allclose(qpos, np.array([r[0] for r in rows]))


def _walk_seconds(walk: np.ndarray, count: int, seed: int) -> list[FootageClip]:
    """``count`` held-out seconds of DeepMimic's walk looped, each a draw of its own (a phase,
    a tempo within 10 %, N(0, 0.01) rad on every hinge: tests/test_two_sample.py's
    `segments`, whose windows these give), the partner 1.5 m ahead along +x."""
    rng = np.random.default_rng(seed)
    period = len(walk) - 1
    step = np.r_[walk[-1, :2] - walk[0, :2], np.zeros(walk.shape[1] - 2)]
    loop = np.concatenate([walk[:-1] + k * step for k in range(4)])
    found = []
    for _ in range(count):
        at = rng.uniform(0, period) + rng.uniform(0.9, 1.1) * np.arange(30)
        q = np.column_stack([np.interp(at, np.arange(len(loop)), c) for c in loop.T])
        q[:, 3:7] /= np.linalg.norm(q[:, 3:7], axis=1, keepdims=True)
        q[:, 7:] += rng.normal(0.0, 0.01, q[:, 7:].shape)
        other = q.copy()
        other[:, :3] += [1.5, 0.0, 0.0]
        found.append(FootageClip("walk", q, other, BoneLengths()))
    return found


def test_the_stage_on_held_out_footage_gives_known_answers(sample_run, run_key, assets):
    """The sample holds no footage out, so the two-sample test's AUC branch runs here: the
    stage on the sample's run, its held-out footage 60 seconds of DeepMimic's walk. The still
    guard's bouts, as the stage simulates them, are told apart (AUC >= 0.95); the stage's own
    two-sample step given 60 more seconds of the walk (the footage against itself) scores
    test_two_sample's walk against walk exactly, 0.59 (0.49-0.69), near 0.5."""
    import tasks.evaluate.stage as stage
    from tasks import deepmimic
    from tasks.evaluate.config import EvaluateConfig
    from tasks.evaluate.two_sample import classifier_test, footage_windows

    walk = deepmimic.retarget(deepmimic.load_deepmimic(deepmimic.clip_path(assets, "walk")))
    heldout = tuple(_walk_seconds(walk, 60, seed=1))
    paths = data_paths(sample_run)
    inputs = dataclasses.replace(
        stage.load_inputs(paths.db, paths.artifacts, run_key), heldout=heldout
    )
    config = EvaluateConfig(episodes=4, episode_frames=60, video_seconds=0)
    out = stage.evaluate(inputs, config)
    rows = {r.policy: r for r in out.rows["evaluate_classifier"] if r.reference == "footage"}
    still = rows["still"]
    assert (still.real_windows, still.simulated_windows) == (60, 8)
    assert still.auc >= 0.95 and still.auc_low >= 0.9, still
    assert out.metrics["two_sample_auc_still"] == still.auc
    assert out.metrics["two_sample_auc"] == rows["adversary"].auc
    assert rows["replay"].reason == NO_TRACKER and "two_sample_gap_closed" not in out.metrics
    # The held-out footage's rates, labelled as a fighter's: the walk steps (DeepMimic's walk is
    # two steps a 1.27 s cycle, 95 a minute; each 1-s clip's touch-downs are counted, also those
    # whose lift-off the clip cut, and one in a clip's first or last two frames is not seen:
    # 75 a minute here) and never punches.
    boxing = {(r.policy, r.metric): r.value for r in out.rows["evaluate_boxing"]}
    assert boxing["footage", "punches_per_min"] == 0.0 == boxing["footage", "punches_per_min_high"]
    low, mean, high = (boxing["footage", f"steps_per_min{s}"] for s in ("_low", "", "_high"))
    assert 60 <= low <= mean <= high <= 130 and out.metrics["footage_steps_per_min"] == mean

    real = footage_windows([(c.qpos, c.other_qpos, c.bones) for c in heldout], 30)
    same = footage_windows(
        [(c.qpos, c.other_qpos, c.bones) for c in _walk_seconds(walk, 60, 2)], 30
    )
    references = {"footage": real, "replay": NO_TRACKER}
    rows, metrics = stage.two_sample_rows(
        references, references, {"adversary": same}, seed=config.seed
    )
    itself = rows[0]
    assert (itself.real_windows, itself.simulated_windows) == (60, 60)
    assert itself.auc == classifier_test(real, same, seed=config.seed).auc
    assert abs(itself.auc - 0.5) < 0.15 and itself.auc_low < 0.5 < itself.auc_high
    assert metrics["two_sample_auc"] == itself.auc
