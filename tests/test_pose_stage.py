"""The pose stage end to end on the real two-person sample, through the CLI and Prefect."""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import (
    child_pids,
    moving_box_frames,
    process_argv,
    query,
    read_video,
    run_cli,
    write_video,
)

import tasks.pose.task
from flows.cli import main
from storage.artifacts import artifact_path

REPO = Path(__file__).resolve().parent.parent


def metrics(data: Path, stage: str = "pose") -> dict[str, float]:
    rows = query(
        data,
        "SELECT m.name, m.value FROM stage_metrics m "
        "JOIN stage_outputs o USING (stage, video_id, key) WHERE m.stage = ? "
        "QUALIFY row_number() OVER (PARTITION BY m.name ORDER BY o.created_at DESC) = 1",
        [stage],
    )
    return dict(rows)


@pytest.fixture
def chunk_calls(monkeypatch) -> list[int]:
    """Chunks the pose stage actually tracked, by chunk index: its executed work."""
    calls: list[int] = []
    real = tasks.pose.task.process_chunk

    def counting(video, span, fps, config, models):
        calls.append(span.index)
        return real(video, span, fps, config, models)

    monkeypatch.setattr(tasks.pose.task, "process_chunk", counting)
    return calls


@pytest.fixture
def processed(sample_run: Path) -> Path:
    return sample_run


def test_both_fighters_tracked_through_every_frame(processed: Path):
    m = metrics(processed)
    assert m["fighters"] == 2
    assert m["both_fighters_share"] >= 0.95
    assert m["adversary_tracks"] == 1 and m["opponent_tracks"] == 1
    assert m["identity_switches"] == 0
    roles = query(processed, "SELECT role, frames_observed FROM pose_tracks ORDER BY track")
    fighters = [frames for role, frames in roles if role != "other"]
    assert len(fighters) == 2 and min(fighters) >= 95
    # The woman standing at the back is not a fighter.
    assert all(frames < 95 for role, frames in roles if role == "other")


def test_keypoints_stored_per_fighter_and_frame(processed: Path):
    rows = query(
        processed,
        "SELECT role, count(*), count(DISTINCT frame) FROM pose_keypoints "
        "GROUP BY role ORDER BY role",
    )
    assert [(r, n) for r, n, _ in rows] == [("adversary", 100), ("opponent", 100)]
    x, raw_x, world, conf = query(
        processed,
        "SELECT x, raw_x, world, confidence FROM pose_keypoints "
        "WHERE role = 'adversary' AND frame = 50",
    )[0]
    assert len(x) == 33 and len(world) == 99
    assert np.isfinite(raw_x).all() and np.isfinite(world).all()
    assert min(conf) >= 0 and max(conf) <= 1
    # BlazePose world points are metric: a person is well under 2.5 m across in any axis.
    assert np.ptp(np.reshape(world, (33, 3)), axis=0).max() < 2.5


def test_refinement_lowers_jitter_on_the_sample(processed: Path):
    m = metrics(processed)
    assert m["jitter_px"] < 0.7 * m["jitter_px_raw"]


def test_overlay_is_browser_video_and_stills_are_pngs(processed: Path):
    media = query(processed, "SELECT kind, frame, artifact FROM pose_media ORDER BY kind, frame")
    artifacts = processed / "artifacts"
    overlay = [a for kind, _, a in media if kind == "overlay"]
    assert len(overlay) == 1
    capture = cv2.VideoCapture(str(artifact_path(artifacts, overlay[0])))
    fourcc = int(capture.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode()
    frames = 0
    while capture.read()[0]:
        frames += 1
    capture.release()
    assert fourcc in ("avc1", "h264") and frames == 100
    stills = [a for kind, _, a in media if kind == "still"]
    assert len(stills) == 4
    for name in stills:
        image = cv2.imread(str(artifact_path(artifacts, name)))
        assert image is not None and max(image.shape[:2]) == 960


def test_rerun_is_cached_and_pick_reuses_the_chunks(
    processed: Path, capsys, sample_video, chunk_calls
):
    base = ["--data", str(processed)]
    argv = process_argv(processed, sample_video, "--ingest-chunk-frames", "30", "--json")
    code, out, _ = run_cli(capsys, *argv)
    assert code == 0 and [s["state"] for s in json.loads(out)] == ["cached"] * 5
    assert chunk_calls == []

    adversary = query(processed, "SELECT track FROM pose_tracks WHERE role = 'adversary'")[0][0]
    opponent = query(processed, "SELECT track FROM pose_tracks WHERE role = 'opponent'")[0][0]
    video_id = json.loads(out)[0]["video_id"]
    code, out, _ = run_cli(
        capsys,
        *base,
        "pick",
        "--video",
        video_id[:8],
        "--track",
        str(opponent),
        "--until",
        "dataset",
        "--ingest-chunk-frames",
        "30",
        "--json",
    )
    # Pose reruns with the pick, and the stages after it; the chunks come from the cache.
    assert code == 0 and [s["state"] for s in json.loads(out)] == ["cached"] + ["done"] * 4
    assert chunk_calls == [], "a new pick recomputed chunks"
    roles = dict(
        query(
            processed,
            "SELECT t.track, t.role FROM pose_tracks t JOIN stage_outputs o "
            "USING (key, video_id) WHERE o.stage = 'pose' "
            "QUALIFY rank() OVER (ORDER BY o.created_at DESC) = 1",
        )
    )
    assert roles[opponent] == "adversary" and roles[adversary] == "opponent"
    assert metrics(processed)["adversary_guessed"] == 0

    code, _, err = run_cli(capsys, *base, "pick", "--video", video_id[:8], "--track", "99")
    assert code == 2 and "--track 99: video" in err and "has no such track" in err


def test_refine_setting_reruns_pose_not_chunks(tmp_path, capsys, sample_video, chunk_calls):
    data = tmp_path / "data"
    base = process_argv(data, sample_video, "--json")
    assert run_cli(capsys, *base)[0] == 0
    assert chunk_calls == [0]
    code, out, _ = run_cli(capsys, *base, "--pose-refine-smoother", "one_euro")
    assert code == 0 and [s["state"] for s in json.loads(out)] == ["cached"] + ["done"] * 4
    assert chunk_calls == [0]


def test_nobody_in_the_video_is_a_clear_failure(tmp_path, capsys):
    video = write_video(tmp_path / "empty_ring.mp4", moving_box_frames(30, (200, 60, 20)))
    data = tmp_path / "data"
    code, _, err = run_cli(capsys, "--data", str(data), "process", str(video), "--adversary", "A")
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and lines == [f"ringside: error: pose: no fighters found in {video}"]
    assert query(data, "SELECT count(*) FROM pose_keypoints")[0][0] == 0
    assert query(data, "SELECT count(*) FROM stage_outputs WHERE stage = 'pose'")[0][0] == 0
    code, out, _ = run_cli(capsys, "--data", str(data), "status", "--json")
    pose = [s for s in json.loads(out) if s["stage"] == "pose"]
    assert pose[0]["state"] == "failed" and "no fighters found" in pose[0]["error"]


def test_one_person_is_one_fighter_and_says_so(tmp_path, capsys, assets):
    video = assets / "samples" / "single_person" / "cam01.mp4"
    data = tmp_path / "data"
    code, out, err = run_cli(
        capsys, "--data", str(data), "process", str(video), "--adversary", "A", "--until", "dataset"
    )
    # Its stages all ran; the dataset is unusable and `process` ends saying why.
    assert code == 2 and "unusable: one fighter only" in err, err
    assert "only one fighter found" in out
    m = metrics(data)
    assert m["fighters"] == 1 and m["both_fighters_share"] == 0
    assert query(data, "SELECT DISTINCT role FROM pose_keypoints") == [("adversary",)]


def test_chunks_run_on_a_dask_cluster(tmp_path, capsys, sample_video, monkeypatch, processed):
    """Two `dask worker` processes started before the command (as on other machines) track the
    chunks, report them to the command's Prefect server and start no Prefect server of their
    own."""
    import dask
    from distributed import Client, LocalCluster

    data = tmp_path / "data"
    worker_env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    # Dask's scratch folder in the test's, not its default /tmp/dask-scratch-space, which
    # outlives the test (the scheduler here and the workers each make one).
    scratch = str(tmp_path / "dask")
    worker_env["DASK_TEMPORARY_DIRECTORY"] = scratch
    with (
        dask.config.set({"temporary-directory": scratch}),
        LocalCluster(
            n_workers=0, processes=False, protocol="tcp", dashboard_address=None
        ) as cluster,
    ):
        workers = [
            subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "distributed.cli.dask_worker",
                    cluster.scheduler_address,
                    "--nthreads",
                    "1",
                    "--no-nanny",
                    "--no-dashboard",
                ],
                cwd=REPO,
                env=worker_env,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )  # fmt: skip
            for _ in range(2)
        ]
        try:
            with Client(cluster) as client:
                client.wait_for_workers(2, timeout=120)
            monkeypatch.setenv("RINGSIDE_DASK_ADDRESS", cluster.scheduler_address)
            code, out, err = run_cli(
                capsys,
                *process_argv(data, sample_video, "--ingest-chunk-frames", "30"),
                "--json",
            )
            started_by_workers = [child for w in workers for child in child_pids(w.pid)]
            # Results the workers computed, by task name: the 4 chunks.
            computed = {
                name: prefix.state_counts["memory"]
                for name, prefix in cluster.scheduler.task_prefixes.items()
            }
        finally:
            for worker in workers:
                worker.terminate()
                worker.wait(timeout=60)
    assert code == 0, err
    assert started_by_workers == []
    assert computed == {"pose_chunk_task": 4}, computed
    assert [s["state"] for s in json.loads(out)] == ["done"] * 5
    # Prefect's database (the tests' shared Prefect home) holds the chunk runs of this command.
    with sqlite3.connect(Path(os.environ["PREFECT_HOME"]) / "prefect.db") as prefect_db:
        chunks = prefect_db.execute(
            "SELECT t.state_type FROM task_run t JOIN flow_run f ON t.flow_run_id = f.id "
            "WHERE t.name LIKE 'pose-chunk-%' AND f.parameters LIKE ?",
            [f"%{data}%"],
        ).fetchall()
    assert chunks == [("COMPLETED",)] * 4
    # The same keypoints as the threaded run of the module's fixture (whose roles a pick may
    # have swapped since, hence the comparison without roles).
    sql = "SELECT DISTINCT frame, raw_x FROM pose_keypoints ORDER BY frame, raw_x"
    assert len(query(data, sql)) == 200
    assert query(data, sql) == query(processed, sql)


def test_a_dask_scheduler_that_does_not_answer_is_one_line(
    tmp_path, capsys, sample_video, monkeypatch
):
    monkeypatch.setenv("RINGSIDE_DASK_ADDRESS", "tcp://127.0.0.1:9")
    code, out, err = run_cli(capsys, *process_argv(tmp_path / "data", sample_video))
    assert code == 2
    (line,) = err.splitlines()
    assert line.startswith("ringside: error: RINGSIDE_DASK_ADDRESS=tcp://127.0.0.1:9: no Dask")
    assert "unset the variable" in line


def test_overlay_starts_where_the_fighters_appear(tmp_path, sample_video):
    """Fighters who appear late in a video are on the review overlay, however short it is:
    1 s of an empty ring, then the sample; an overlay of 0.5 s starts on the sample's part."""
    _, sample = read_video(sample_video)
    empty = [np.full_like(sample[0], 90) for _ in range(60)]
    video = write_video(tmp_path / "late.mp4", empty + sample, fps=60.0)
    data = tmp_path / "data"
    code = main(
        ["--data", str(data), "process", str(video), "--adversary", "A", "--until", "pose",
         "--pose-overlay-seconds", "0.5"]
    )  # fmt: skip
    assert code == 0
    ((start, name),) = query(data, "SELECT frame, artifact FROM pose_media WHERE kind = 'overlay'")
    assert start >= 60
    _, drawn = read_video(artifact_path(data / "artifacts", name))
    assert len(drawn) == 30
    # The skeletons are drawn: the overlay differs from the footage it was drawn on.
    footage = cv2.resize(sample[start - 60], drawn[0].shape[1::-1], interpolation=cv2.INTER_AREA)
    assert np.abs(drawn[0].astype(int) - footage.astype(int)).mean() > 1.0


def test_two_pairs_side_by_side_get_a_note_and_one_pair_reaches_the_dataset(
    tmp_path, capsys, sample_video
):
    """The sample twice, side by side: four people, two pairs. Whichever two the stage takes,
    the choice is barely better than the next, and the analyst is told which tracks to look
    at (before, a crowd gave only "the adversary is a guess")."""
    _, frames = read_video(sample_video)
    tiled = [
        np.hstack([cv2.resize(f, (272, 480), interpolation=cv2.INTER_AREA)] * 2) for f in frames
    ]
    video = write_video(tmp_path / "two_pairs.mp4", tiled, fps=60.0)
    data = tmp_path / "data"
    code, out, err = run_cli(capsys, *process_argv(data, video))
    assert code == 0, err
    m = metrics(data)
    assert m["fighter_choice_margin"] < 0.1 and m["tracks"] >= 4
    assert "may not be two people fighting" in out and "next candidates: tracks" in out, out
    # Through to the dataset: the two fighters are one pair, on one copy (not a fighter and a
    # stranger from the other copy), and they stand as far apart as in the sample.
    sides = query(
        data,
        "SELECT frame, list_avg(x) >= 272 AS right_copy FROM pose_keypoints ORDER BY frame, role",
    )
    together = {}
    for frame, right in sides:
        together.setdefault(frame, []).append(right)
    both = [s for s in together.values() if len(s) == 2]
    assert len(both) >= 95 and all(s[0] == s[1] for s in both)
    lift = metrics(data, "lift")
    assert 1.0 < lift["fighter_distance_mean_m"] < 1.6, lift["fighter_distance_mean_m"]
    assert query(data, "SELECT count(*) FROM dataset_transitions WHERE kind = 'interaction'")[0][0]
