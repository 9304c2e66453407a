"""The train stage on the demo's dataset: the CLI, fail-fast checks, a killed run resuming."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import TINY_TRAIN_FLAGS, copy_data, query, render_page, run_cli

from dashboards import queries
from dashboards.opponent import TRACK_TILES
from models.maaip.config import (
    DiscriminatorConfig,
    EnvConfig,
    NetworkConfig,
    PPOConfig,
)
from models.maaip.trainer import Trainer
from models.tracking.config import TrackConfig
from storage.artifacts import artifact_path, read_bytes
from storage.db import connect
from storage.paths import data_paths
from storage.records import output_metrics
from tasks.config import build
from tasks.dataset.config import DatasetConfig
from tasks.dataset.demonstrations import load_demonstrations
from tasks.dataset.store import dataset_info, footage_clips, record_dataset
from tasks.opponent.export import matched_footage, replayed_footage, trained_policy
from tasks.opponent.folder import load_opponent
from tasks.roles import ROLES
from tasks.train.config import TrainConfig
from tasks.train.run import train
from tasks.train.store import _fits, warm_start_source
from tasks.train.tracker import SPLITS

TINY = TrainConfig(
    iterations=4,
    checkpoint_every=2,
    network=NetworkConfig(hidden="16,16"),
    discriminator=DiscriminatorConfig(samples_per_update=16, updates_per_iteration=1),
    ppo=PPOConfig(horizon=4, minibatch_size=16, epochs=1),
    env=EnvConfig(num_envs=4),
)
TIMING = {"collect_s", "rewards_s", "discriminators_s", "ppo_s", "env_steps_per_s"}


@pytest.fixture(scope="module")
def dataset_key(sample_dataset) -> str:
    return sample_dataset


def test_a_tracker_run_tracks_every_clip_of_its_dataset_and_the_dataset_page_shows_them(
    tmp_path, capsys, monkeypatch, sample_run, dataset_key
):
    from streamlit.testing.v1 import AppTest

    # A copy: the tracker must not become the newest run of the shared sample's dataset. In it,
    # beside each of the sample's clips, a short one: 10 of its steps, from its second on.
    data = copy_data(sample_run, tmp_path / "data")
    with connect(data_paths(data).db) as con:
        con.execute(
            "INSERT INTO dataset_clips (key, video_id, clip, kind, role, shot, split, start_step, "
            "end_step) SELECT key, video_id, clip + 1000, kind, role, shot, split, start_step + 1, "
            "start_step + 11 FROM dataset_clips WHERE kind = 'interaction'"
        )
    argv = [
        *["--data", str(data), "train", "--dataset", dataset_key, *TINY_TRAIN_FLAGS],
        *["--train-objective", "track", "--train-iterations", "2", "--json"],
        *["--train-track-gate-every", "1"],
    ]
    code, out, err = run_cli(capsys, *argv)
    assert code == 0, err
    (summary,) = json.loads(out)
    key = summary["key"]
    with connect(data_paths(data).db, read_only=True) as con:
        clips = {
            split: {role: footage_clips(con, dataset_key, role, split) for role in ROLES}
            for split in SPLITS
        }
        tracker, rows = queries.dataset_tracking(con, dataset_key)
        metrics = output_metrics(con, "train", dataset_key, key)
    assert tracker == key
    # Every clip of two frames or more, each fighter's by its own agent, once per split.
    expected = {
        (split, agent, c.name): len(c.qpos)
        for split, by_role in clips.items()
        for agent, role in enumerate(ROLES)
        for c in by_role[role]
        if len(c.qpos) >= 2
    }
    assert expected and {(r["split"], r["agent"], r["clip"]) for r in rows} == set(expected)
    for r in rows:
        frames = expected[r["split"], r["agent"], r["clip"]]
        # Tracked from the first frame: at most the clip's steps, all of them if finished.
        assert 1 <= r["frames"] <= frames - 1
        assert not r["finished"] or r["frames"] == frames - 1
        assert 0 <= r["body_error_cm"] < 100 and 0 <= r["root_error_cm"] < 100
    # The short clips the 2-iteration tracker (its corrections still near zero) follows to the
    # end, all 9 steps (measured: 2.2 and 3.3 cm body error).
    short = [r for r in rows if expected[r["split"], r["agent"], r["clip"]] == 10]
    assert len(short) == len(rows) // 2, short
    assert all(r["finished"] and r["frames"] == 9 for r in short), short
    train_rows = [r for r in rows if r["split"] == "train"]
    assert metrics["track_finished_pct"] == pytest.approx(
        100 * sum(r["finished"] for r in train_rows) / len(train_rows)
    )
    assert metrics["track_body_error_cm"] == pytest.approx(
        sum(r["body_error_cm"] for r in train_rows) / len(train_rows)
    )
    held_out = any(r["split"] == "validation" for r in rows)
    assert ("track_body_error_cm_held_out" in metrics) == held_out
    assert "body_error_cm" in metrics and "episode_length_s" in metrics
    # A gate check after each iteration: the last one is the final policy on the train clips,
    # so it gives the train split's figures; a 2-iteration tracker (the long clips lost) does
    # not hold the gate.
    checks = query(
        data,
        "SELECT iteration, name, value FROM train_iterations WHERE key = ? AND name LIKE 'gate_%' "
        "ORDER BY iteration, name",
        [key],
    )
    last = {name: value for iteration, name, value in checks if iteration == 1}
    assert {i for i, _, _ in checks} == {0, 1}
    assert last["gate_finished_pct"] == pytest.approx(metrics["track_finished_pct"])
    assert last["gate_body_error_cm"] == pytest.approx(metrics["track_body_error_cm"])
    assert last["gate_met"] == 0.0 and last["gate_held"] == 0.0
    assert metrics["track_gate_held"] == 0.0 and metrics["track_gate_checks"] == 2.0
    assert metrics["track_gate_met_of_last"] == 0.0

    code, out, _ = run_cli(capsys, *argv)
    assert code == 0 and json.loads(out)[0]["state"] == "cached"
    # A tracker follows clips and fights no one: evaluating or exporting it is refused.
    for command in ("evaluate", "export"):
        code, _, err = run_cli(capsys, "--data", str(data), command, "--run", key[:12])
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and "is a 'track' run" in lines[0], err
    # As the matched opponent it would play the train footage its tracker finished, the rest
    # named as left out: here the short clips, too short for the matcher's second of future,
    # so the export is refused in one line and writes nothing.
    trained = trained_policy(data_paths(data).db, data_paths(data).artifacts, key[:12])
    footage = matched_footage(data_paths(data).db, trained, 0)
    adversary_rows = [r for r in rows if r["split"] == "train" and r["agent"] == 0]
    assert {name for name, _, _ in footage.clips} == {
        r["clip"] for r in adversary_rows if r["finished"]
    }
    assert set(footage.left_out) == {r["clip"] for r in adversary_rows if not r["finished"]}
    assert all(len(own) == 10 for _, own, _ in footage.clips) and footage.left_out
    # A tracker trained in bouts played all of it through its matchers: it plays all of it.
    in_bouts = dataclasses.replace(
        trained.config, track=dataclasses.replace(trained.config.track, bouts=True)
    )
    everything = matched_footage(
        data_paths(data).db, dataclasses.replace(trained, config=in_bouts), 0
    )
    assert {name for name, _, _ in everything.clips} == {r["clip"] for r in adversary_rows}
    assert everything.left_out == ()
    # Or its tracker's own replay of that footage, as filmed in MuJoCo: each clip from its
    # first frame, the frame each step reached with the footage's other fighter at that frame,
    # and each step's body error; a replay that fell keeps what came half a second before.
    replayed = replayed_footage(data_paths(data).db, trained, 0)
    assert replayed.source == "replay" and replayed.body_error is not None
    assert {n for n, _, _ in replayed.clips} | set(replayed.left_out) == {
        r["clip"] for r in adversary_rows
    }
    filmed = {name: (own, other) for name, own, other in everything.clips}
    for (name, own, other), error in zip(replayed.clips, replayed.body_error, strict=True):
        assert len(own) == len(other) == len(error) <= len(filmed[name][0]) - 1
        np.testing.assert_array_equal(other, filmed[name][1][1 : len(own) + 1])
        # Simulated, not copied: off the footage's frames, within the drift that ends a run.
        gap = np.linalg.norm(own[:, :3] - filmed[name][0][1 : len(own) + 1, :3], axis=-1)
        assert 0 < gap.max() < trained.config.track.root_limit_m, (name, gap)
        assert gap[0] < 0.02 and np.nanmax(error) < 0.5
    # The short clips it finished are whole (9 steps from the first frame).
    lengths = {n: len(own) for n, own, _ in replayed.clips}
    assert {lengths.get(n) for n, own, _ in everything.clips if len(own) == 10} == {9}
    for motion in ("footage", "replay"):
        out_dir = tmp_path / "matched"
        argv = [
            *["--data", str(data), "export", "--run", key[:12], "--matched", "--out"],
            *[str(out_dir), "--matched-motion", motion],
        ]
        code, _, err = run_cli(capsys, *argv)
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1, err
        assert "no clip is longer than the matcher's future" in err
        assert not out_dir.exists()
    # Nor does a MAAIP run start from a tracker's networks (other observations).
    (stored,) = query(
        data, "SELECT config FROM stage_outputs WHERE stage = 'train' AND key = ?", [key]
    )
    settings = json.loads(stored[0])
    assert not _fits(settings, TINY)
    assert _fits(settings, dataclasses.replace(TINY, objective="track"))
    # Nor a tracker whose value reads the partner from one whose value does not, and a tracker
    # stored before that setting existed had one that did.
    partner = dataclasses.replace(
        TINY, objective="track", track=TrackConfig(value_sees_partner=True)
    )
    assert not _fits(settings, partner)
    del settings["track"]["value_sees_partner"]
    assert _fits(settings, partner)
    assert not _fits(settings, dataclasses.replace(TINY, objective="track"))

    # MAAIP from the tracker: its policy distilled into the run's before the first iteration.
    distilled = [
        *["--data", str(data), "train", "--dataset", dataset_key, *TINY_TRAIN_FLAGS],
        *["--train-iterations", "2", "--train-distill-rounds", "2", "--train-distill-steps", "5"],
        *["--train-distill-from-tracker", "true", "--json"],
    ]
    code, out, err = run_cli(capsys, *distilled)
    assert code == 0, err
    (maaip,) = json.loads(out)
    assert maaip["notes"] == [
        f"started from tracker run {key[:12]} distilled into the policy (2 rounds)"
    ]
    with connect(data_paths(data).db, read_only=True) as con:
        figures = output_metrics(con, "train", dataset_key, maaip["key"])
    assert figures["distill_samples_1"] == 2 * figures["distill_samples_0"] > 0
    assert figures["distill_loss_0"] > 0 and figures["distill_episode_s_1"] > 0
    # Without a tracker on the dataset, the setting is refused in one line, before Prefect.
    code, _, err = run_cli(capsys, *[str(sample_run) if a == str(data) else a for a in distilled])
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "no finished tracker run" in lines[0], err

    monkeypatch.setenv("RINGSIDE_DATA", str(data))
    app = AppTest.from_function(render_page, args=("dataset",), default_timeout=60)
    app.query_params["dataset"] = dataset_key
    app.run()
    assert not app.exception, app.exception
    assert "Can a physics body follow each clip?" in [h.value for h in app.subheader]
    (shown,) = [t for t in app.table if "body_error_cm" in t.value.columns]
    assert len(shown.value) == len(rows)
    # The training page shows a tracker's own figures, not the discriminators' it has none of.
    app = AppTest.from_function(render_page, args=("training",), default_timeout=60)
    app.query_params["run"] = key
    app.run()
    assert not app.exception, app.exception
    tiles = {m.label: m.value for m in app.metric}
    assert list(tiles) == list(TRACK_TILES.values()) and "–" not in tiles.values(), tiles
    # And its gate checks, not held.
    assert "The gate" in [h.value for h in app.subheader]
    (gates,) = [t for t in app.table if "clips finished (%)" in t.value.columns]
    assert list(gates.value["held"]) == ["no", "no"]
    assert any("**not held** after 2 iterations" in c.value for c in app.caption)

    # With a gate any tracker meets, held at 2 of the last 2 checks: the run stops there,
    # 2 iterations of the 6 it was given.
    loose = [
        *["--data", str(data), "train", "--dataset", dataset_key, *TINY_TRAIN_FLAGS],
        *["--train-objective", "track", "--train-iterations", "6", "--json"],
        *["--train-track-gate-every", "1", "--train-track-gate-window", "2"],
        *["--train-track-gate-needed", "2", "--train-track-gate-finished-pct", "0"],
        *["--train-track-gate-body-error-cm", "1000", "--train-track-gate-root-error-cm", "1000"],
    ]
    code, out, err = run_cli(capsys, *loose)
    assert code == 0, err
    with connect(data_paths(data).db, read_only=True) as con:
        held = output_metrics(con, "train", dataset_key, json.loads(out)[0]["key"])
    assert held["iterations"] == 2.0 and held["track_gate_held"] == 1.0
    assert held["track_gate_met_of_last"] == 2.0
    app = AppTest.from_function(render_page, args=("training",), default_timeout=60)
    app.query_params["run"] = json.loads(out)[0]["key"]
    app.run()
    assert any("**held** from the check after 2 iterations on" in c.value for c in app.caption)


def test_train_cli_runs_and_caches(capsys, sample_run, dataset_key):
    # A seed of its own, so that no other test's tiny run is this one (the first call must train).
    base = [
        *["--data", str(sample_run), "train", "--dataset", dataset_key, *TINY_TRAIN_FLAGS],
        *["--train-seed", "7"],
    ]
    code, out, err = run_cli(capsys, *base, "--train-iterations", "2", "--json")
    assert code == 0, err
    (summary,) = json.loads(out)
    assert summary["stage"] == "train" and summary["state"] == "done"
    curves = query(
        sample_run,
        "SELECT count(DISTINCT iteration) FROM train_iterations WHERE key = ? "
        "AND name = 'reward_total'",
        [summary["key"]],
    )
    assert curves == [(2,)]
    code, out, _ = run_cli(capsys, *base, "--train-iterations", "2", "--json")
    assert code == 0 and json.loads(out)[0]["state"] == "cached"
    code, out, _ = run_cli(capsys, "--data", str(sample_run), "metrics", "--stage", "train")
    assert code == 0 and "falls_per_min" in out and "reward_interaction" in out
    curves = ["--data", str(sample_run), "curves", "--run", summary["key"][:10], "--every", "1"]
    code, out, _ = run_cli(capsys, *curves, "--json")
    rows = json.loads(out)
    assert code == 0 and [r["iterations"] for r in rows] == ["0-0", "1-1"]
    # A block not yet full names the iterations it holds (the dashboard's "newest point").
    code, out, _ = run_cli(capsys, *curves[:-1], "5", "--json")
    assert code == 0 and [r["iterations"] for r in json.loads(out)] == ["0-1"]
    falls = query(
        sample_run,
        "SELECT value FROM train_iterations WHERE key = ? AND name = 'falls_per_min' "
        "ORDER BY iteration",
        [summary["key"]],
    )
    assert [r["falls_per_min"] for r in rows] == [v for (v,) in falls]
    code, _, err = run_cli(capsys, "--data", str(sample_run), "curves", "--run", "zzz")
    assert code == 2 and "matches no training run" in err

    # The run's adversary as an opponent folder that onnxruntime loads.
    export = ["--data", str(sample_run), "export", "--run", summary["key"][:10], "--json"]
    code, out, err = run_cli(capsys, *export)
    assert code == 0, err
    made = json.loads(out)
    opponent = load_opponent(Path(made["folder"]))
    assert made["run_key"] == summary["key"] and made["iteration"] == 2
    assert opponent.agent == 0 and opponent.manifest["dataset_key"] == dataset_key
    assert "falls_per_min" in opponent.manifest["metrics"]
    code, _, err = run_cli(capsys, "--data", str(sample_run), "export", "--run", "zzz")
    assert code == 2 and "matches no finished training run" in err


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--dataset", "0123456789abcdef01234567"], "no dataset '0123456789abcdef01234567'"),
        (["--train-reward-w-motion", "-1"], "train.reward.w_motion must be non-negative"),
        (["--train-reward-control-task", "damage_min"], "train.reward.w_control must be positive"),
        (["--train-ppo-minibatch-size", "100000"], "must not exceed the batch"),
    ],
)
def test_bad_training_input_fails_fast(capsys, sample_run, dataset_key, flags, message):
    argv = ["--data", str(sample_run), "train", "--dataset", dataset_key, *flags]
    before = query(sample_run, "SELECT count(*) FROM train_iterations")
    code, _, err = run_cli(capsys, *argv)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert query(sample_run, "SELECT count(*) FROM train_iterations") == before


def test_a_killed_run_resumes_where_it_stopped(sample_run, dataset_key):
    paths = data_paths(sample_run)
    common = {"db": paths.db, "artifacts": paths.artifacts, "dataset_key": dataset_key}
    train(**common, key="whole", config=TINY)

    with pytest.raises(KeyboardInterrupt):
        train(**common, key="killed", config=TINY, stop=lambda iteration: iteration == 3)
    # Killed after the third iteration (index 2), which was not checkpointed: the checkpoint
    # after two iterations is the run's only one, and its metrics are all that was written.
    saved = query(sample_run, "SELECT iteration FROM train_checkpoints WHERE key = 'killed'")
    assert saved == [(2,)]
    assert query(
        sample_run, "SELECT max(iteration) FROM train_iterations WHERE key = 'killed'"
    ) == [(1,)]
    train(**common, key="killed", config=TINY)

    def curves(key):
        rows = query(
            sample_run,
            "SELECT iteration, name, value FROM train_iterations WHERE key = ? ORDER BY ALL",
            [key],
        )
        return [r for r in rows if r[1] not in TIMING]

    # One checkpoint per run is kept; the older ones' files are gone.
    assert query(sample_run, "SELECT count(*) FROM train_checkpoints WHERE key = 'whole'") == [(1,)]
    kept = query(
        sample_run,
        "SELECT artifact FROM train_checkpoints UNION SELECT artifact FROM train_policies",
    )
    assert sorted(p.name for p in paths.artifacts.rglob("*.pt")) == sorted(a for (a,) in kept)

    resumed = curves("killed")
    assert [r[0] for r in resumed if r[1] == "reward_total"] == [0, 1, 2, 3]
    assert resumed == curves("whole")


def test_a_killed_tracker_run_resumes_to_the_run_it_would_have_been(sample_run, dataset_key):
    paths = data_paths(sample_run)
    common = {"db": paths.db, "artifacts": paths.artifacts, "dataset_key": dataset_key}
    config = dataclasses.replace(TINY, objective="track")
    whole = train(**common, key="track-whole", config=config)
    with pytest.raises(KeyboardInterrupt):
        train(**common, key="track-killed", config=config, stop=lambda iteration: iteration == 3)
    resumed = train(**common, key="track-killed", config=config)
    assert resumed.rows["train_tracking"] == whole.rows["train_tracking"]
    rows = query(
        sample_run,
        "SELECT key, iteration, name, value FROM train_iterations WHERE key LIKE 'track-%' "
        "ORDER BY ALL",
    )
    curves = {
        key: [r[1:] for r in rows if r[0] == key and r[2] not in TIMING]
        for key in ("track-whole", "track-killed")
    }
    assert curves["track-killed"] == curves["track-whole"]
    assert {r[2] for r in rows} >= {"body_error_cm", "reward_pose"}


def test_a_run_with_a_time_budget_ends_at_the_first_checkpoint_after_it(sample_run, dataset_key):
    paths = data_paths(sample_run)
    budget = dataclasses.replace(TINY, iterations=1000, minutes=1e-6)
    out = train(
        db=paths.db, artifacts=paths.artifacts, dataset_key=dataset_key, key="timed", config=budget
    )
    # The budget ran out in the first iteration; the run stops at the checkpoint after two.
    assert out.rows["train_policies"][0].iteration == 2 and out.metrics["iterations"] == 2
    assert query(sample_run, "SELECT iteration FROM train_checkpoints WHERE key = 'timed'") == [
        (2,)
    ]
    with pytest.raises(ValueError, match="train.minutes"):
        dataclasses.replace(TINY, minutes=-1.0)


def test_a_training_killed_with_sigkill_shows_interrupted_and_the_same_command_resumes(
    tmp_path, capsys, sample_run, dataset_key
):
    data = copy_data(sample_run, tmp_path / "data")
    train_run = [
        *["--data", str(data), "train", "--dataset", dataset_key, *TINY_TRAIN_FLAGS],
        *["--train-iterations", "100", "--train-checkpoint-every", "5", "--train-seed", "3"],
    ]
    # The copied data holds other tests' runs and checkpoints: wait for this run's.
    known = [key for (key,) in query(data, "SELECT DISTINCT key FROM train_checkpoints")]
    mine = "SELECT iteration FROM train_checkpoints WHERE NOT list_contains(?::VARCHAR[], key)"
    command = subprocess.Popen(
        [sys.executable, "-m", "flows.cli", *train_run],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    saved: list[tuple] = []
    deadline = time.monotonic() + 180
    while not saved and time.monotonic() < deadline and command.poll() is None:
        time.sleep(0.5)
        try:  # the run holds the database's write lock for moments at a time
            saved = query(data, mine, [known])
        except Exception:  # noqa: BLE001 (DuckDB's lock error has no class of its own)
            continue
    assert saved and command.poll() is None, "the run saved no checkpoint while it ran"
    command.kill()
    command.wait()

    code, out, _ = run_cli(capsys, "--data", str(data), "status", "--json")
    (training,) = [
        r for r in json.loads(out) if r["stage"] == "train" and r["video_id"] == dataset_key
    ]
    assert code == 0
    assert training["state"] == "interrupted" and "killed or crashed" in training["error"]
    with connect(data_paths(data).db, read_only=True) as con:
        (run,) = [r for r in queries.training_runs(con) if r["key"] == training["key"]]
    assert run["state"] == "interrupted"
    # The resumed run keeps what its newest checkpoint covers (the seconds each iteration took
    # differ on a recomputation): it picks up where it stopped.
    (newest,) = query(data, mine.replace("iteration", "max(iteration)", 1), [known])[0]
    timings = (
        "SELECT iteration, value FROM train_iterations WHERE key = ? AND name = 'collect_s' "
        "AND iteration < ? ORDER BY iteration"
    )
    kept = query(data, timings, [training["key"], newest])
    assert len(kept) == newest

    code, out, err = run_cli(capsys, *train_run, "--json")
    assert code == 0, err
    assert json.loads(out)[0]["state"] == "done"
    rows = query(
        data,
        "SELECT count(*), count(DISTINCT iteration), min(iteration) FROM train_iterations "
        "WHERE key = ? AND name = 'reward_total'",
        [training["key"]],
    )
    assert rows == [(100, 100, 0)], "iterations lost or written twice"
    code, out, _ = run_cli(capsys, "--data", str(data), "status", "--json")
    states = [r for r in json.loads(out) if r["stage"] == "train" and r["video_id"] == dataset_key]
    assert [(r["key"], r["state"]) for r in states] == [(training["key"], "done")]
    assert query(data, timings, [training["key"], newest]) == kept


def test_a_run_on_a_later_dataset_of_the_adversary_starts_from_its_previous_networks(
    tmp_path, capsys, sample_run, dataset_key
):
    data = copy_data(sample_run, tmp_path / "data")
    base = ["--data", str(data), "train", *TINY_TRAIN_FLAGS, "--train-iterations", "2", "--json"]
    code, out, err = run_cli(capsys, *base, "--dataset", dataset_key, "--train-seed", "11")
    assert code == 0, err
    previous = json.loads(out)[0]["key"]
    # The same footage assembled again with other settings: a new dataset of the same
    # adversary, made later, on the same humanoids.
    with connect(data_paths(data).db) as con:
        info = dataset_info(con, dataset_key)
        config = build(DatasetConfig, {**info.config, "validation_fraction": 0.3}, section="d")
        later, new = record_dataset(con, info.adversary, config, list(info.members))
        assert new and later != dataset_key
        chosen = warm_start_source(con, later, TINY)
        assert chosen is not None and chosen.dataset_key == dataset_key
        assert warm_start_source(con, later, dataclasses.replace(TINY, warm_start=False)) is None
        other_sizes = dataclasses.replace(TINY, network=NetworkConfig(hidden="8,8"))
        assert warm_start_source(con, later, other_sizes) is None
        # Only earlier datasets count: the first dataset has no run to start from.
        assert warm_start_source(con, dataset_key, TINY) is None
        demos = load_demonstrations(con, later)
    newest = query(
        data,
        "SELECT p.key FROM train_policies p JOIN stage_outputs o ON o.stage = 'train' "
        "AND o.key = p.key WHERE p.video_id = ? ORDER BY o.created_at DESC LIMIT 1",
        [dataset_key],
    )
    assert chosen.run_key == newest[0][0] == previous

    # The new run starts from those networks (not a fresh initialisation), says so, and its
    # key names them; with warm starts off it is another run.
    trainer = Trainer(TINY, demos)
    try:
        fresh = {k: v.clone() for k, v in trainer.nets.policy.state_dict().items()}
        trainer.warm_start(read_bytes(data_paths(data).artifacts, chosen.artifact))
        loaded = trainer.nets.policy.state_dict()
    finally:
        trainer.close()
    source = torch.load(
        artifact_path(data_paths(data).artifacts, chosen.artifact), weights_only=False
    )
    source = source["networks"]["policy"]
    assert all(torch.equal(loaded[k], source[k]) for k in source)
    assert not all(torch.equal(loaded[k], fresh[k]) for k in fresh)

    code, out, err = run_cli(capsys, *base, "--dataset", later)
    assert code == 0, err
    (warm,) = json.loads(out)
    assert warm["state"] == "done"
    assert any(f"started from the networks of run {previous[:12]}" in n for n in warm["notes"])
    code, out, err = run_cli(capsys, *base, "--dataset", later, "--train-warm-start", "false")
    assert code == 0, err
    (cold,) = json.loads(out)
    assert cold["key"] != warm["key"] and not cold["notes"]
    # `train.warm_from` names the run to start from, on any dataset; a name that fits no
    # finished run, or a run of other networks, is refused in one line.
    code, out, err = run_cli(
        capsys, *base, "--dataset", dataset_key, "--train-warm-from", cold["key"][:12]
    )
    assert code == 0, err
    (named,) = json.loads(out)
    assert any(f"started from the networks of run {cold['key'][:12]}" in n for n in named["notes"])
    for run, said in (("0" * 12, "matches no finished training run"), (previous[:12], "networks")):
        flags = [
            "--dataset",
            dataset_key,
            "--train-warm-from",
            run,
            "--train-network-hidden",
            "8,8",
        ]
        code, out, err = run_cli(capsys, *base, *flags)
        assert code != 0 and said in err and len(err.strip().splitlines()) == 1, err
