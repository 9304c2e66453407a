"""One registry of stages (`tasks.registry`): what it derives, and a stage from outside joining
the pipeline with its folder, one registry entry and one migration, no other file changed."""

from __future__ import annotations

import json

import pytest
from conftest import copy_data, process_argv, query, run_cli
from pace import PACE

from dashboards import queries
from storage.db import connect
from tasks import registry
from tasks.registry import Stage, Subject

BUILT_IN = ("ingest", "pose", "lift", "dataset", "train", "evaluate")


def test_the_registry_orders_and_derives_the_stages():
    assert registry.names() == BUILT_IN
    assert registry.per_video() == ("ingest", "pose", "lift", "dataset")
    assert registry.until("lift") == ("ingest", "pose", "lift")
    assert registry.until(None) == BUILT_IN
    assert registry.downstream("lift") == ("lift", "dataset", "train", "evaluate")
    with pytest.raises(ValueError, match="unknown upstream"):
        registry.register(Stage("extra", Subject.VIDEO, object, ("nowhere",), PACE.inputs, "x:y"))
    with pytest.raises(ValueError, match="registered already"):
        registry.register(Stage("pose", Subject.VIDEO, object, (), PACE.inputs, "x:y"))
    with pytest.raises(ValueError, match="lowercase"):
        registry.register(Stage("pose_2", Subject.VIDEO, object, (), PACE.inputs, "x:y"))
    with pytest.raises(ValueError, match="the upstream outputs it reads"):
        registry.register(Stage("extra", Subject.VIDEO, object, ("pose",), PACE.inputs, "x:y"))
    with pytest.raises(ValueError, match="upstream of"):
        registry.unregister("lift")
    assert registry.names() == BUILT_IN


def test_a_stage_from_outside_runs_through_process_status_check_rerun_and_the_dashboard(
    sample_run, sample_video, tmp_path, capsys
):
    data = copy_data(sample_run, tmp_path / "data")
    argv = process_argv(data, sample_video, "--ingest-chunk-frames", "30", until="pace")

    def outputs() -> dict[str, int]:
        return dict(query(data, "SELECT stage, count(*) FROM stage_outputs GROUP BY stage"))

    before = outputs()  # the shared run may hold other tests' reruns
    with registry.registered(PACE):
        assert registry.until("pace") == ("ingest", "pose", "lift", "pace")
        assert registry.downstream("lift") == ("lift", "dataset", "train", "evaluate", "pace")

        code, _, err = run_cli(capsys, *argv)
        assert code == 0, err
        speeds = dict(query(data, "SELECT role, speed_m_s FROM pace_speeds"))
        assert set(speeds) == {"adversary", "opponent"}
        # Two people walking: a median pelvis speed of a walk, neither still nor running.
        assert all(0.3 < v < 2.5 for v in speeds.values()), speeds
        assert outputs() == {**before, "pace": 1}  # the stages it needs reused

        # Its settings are flags and a section of their own: changing one reruns it alone.
        code, _, err = run_cli(capsys, *argv, "--pace-percentile", "90")
        assert code == 0, err
        assert outputs() == {**before, "pace": 2}
        assert max(v for (v,) in query(data, "SELECT speed_m_s FROM pace_speeds")) > max(
            speeds.values()
        )

        code, out, _ = run_cli(capsys, "--data", str(data), "status", "--json")
        assert code == 0
        states = {r["stage"]: r["state"] for r in json.loads(out)}
        assert states["pace"] == "done"

        (video_id,) = query(data, "SELECT video_id FROM videos")[0]
        code, _, err = run_cli(
            capsys,
            "--data", str(data), "rerun", "pace", "--video", video_id[:12], "--until", "pace",
            "--ingest-chunk-frames", "30",
        )  # fmt: skip
        assert code == 0, err
        runs = query(
            data, "SELECT count(*) FROM stage_runs WHERE stage = 'pace' AND state = 'done'"
        )
        assert runs[0][0] == 3

        code, out, err = run_cli(capsys, "--data", str(data), "check", "--json")
        assert code == 0, err
        assert json.loads(out)["problems"] == []

        assert "pace" in queries.metric_stages()
        with connect(data / "ringside.duckdb", read_only=True) as con:
            metrics = {r["name"] for r in queries.stage_metrics(con, "pace")}
        assert metrics == {"adversary_speed_m_s", "opponent_speed_m_s"}
    assert registry.names() == BUILT_IN
