"""An honest verdict per dataset: one that cannot be trained on is called unusable in one line
saying why, by `process` (exit 2, with everything the stages computed kept), `datasets`,
`status`, the dashboard's dataset page and `train`. Before, footage of one person and a
dataset without a single adversary frame went through with exit 0, were listed like any other,
and training then advised lowering dataset.min_clip_s."""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

import pytest
from conftest import copy_data, process_argv, query, render_page, run_cli

from flows.cli.environment import EXIT_BAD_INPUT
from models.humanoid.motion import RATE
from storage.db import connect
from tasks.dataset.store import dataset_verdicts, upstream_lift_key
from tasks.dataset.verdict import unusable_reason

SECOND = int(RATE)  # steps


@pytest.mark.parametrize(
    ("clips", "reason"),
    [
        (
            [("single", "adversary", "train", SECOND)] * 2 + [("interaction", None, "train", 40)],
            None,
        ),
        ([("single", "extra", "train", 90)], "no fighter was lifted"),
        ([("single", "opponent", "train", 3 * SECOND)], "no adversary frames"),
        ([("single", "adversary", "validation", 2 * SECOND)], "one fighter only"),
        (
            [("single", "adversary", "train", SECOND), ("single", "opponent", "train", SECOND)],
            "no interaction",
        ),
        (
            [
                ("single", "adversary", "train", SECOND),
                ("single", "opponent", "validation", SECOND),
                ("interaction", None, "validation", SECOND),
            ],
            "empty train split: its 1 interaction clips",
        ),
    ],
)
def test_the_verdict_names_the_first_missing_link(clips, reason):
    found = unusable_reason(clips)
    if reason is None:
        assert found is None
    else:
        assert found.startswith(reason) and "\n" not in found, found


def test_the_verdict_says_how_long_the_one_fighter_was_lifted():
    found = unusable_reason([("single", "opponent", "train", 3 * SECOND)] * 2)
    assert "only the opponent (6.0 s)" in found, found


def _process(data: Path, video: Path, adversary: str, *flags: str) -> tuple[int, str, str]:
    """`ringside process` up to the dataset: (exit code, stdout, stderr)."""
    from flows.cli import main

    argv = process_argv(data, video, *flags)
    argv[argv.index("--adversary") + 1] = adversary
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def _errors(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.strip()]


@pytest.fixture(scope="module")
def data(sample_run: Path, tmp_path_factory) -> Path:
    """A copy of the sample's data directory (its usable dataset included) for this module's
    runs, which would add unusable datasets to the shared one."""
    return copy_data(sample_run, tmp_path_factory.mktemp("verdict") / "data")


@pytest.fixture(scope="module")
def one_person(data: Path, assets: Path) -> tuple[int, str, str]:
    """The bundled footage of one person walking, as adversary "solo"."""
    return _process(data, assets / "samples" / "single_person" / "cam01.mp4", "solo")


@pytest.fixture(scope="module")
def never_lifted(data: Path, sample_video: Path) -> tuple[int, str, str]:
    """The sample with the lift believing nobody further than 2.8 m from the camera: the
    adversary (the guess, the person further off) is refused in every frame, the opponent kept
    (the test checks both on the lift's rows)."""
    return _process(data, sample_video, "A", "--lift-gates-max-depth-m", "2.8")


def _dataset_of(data: Path, adversary: str) -> str:
    return query(
        data,
        "SELECT dataset_key FROM datasets WHERE adversary = ? ORDER BY created_at DESC LIMIT 1",
        [adversary],
    )[0][0]


def test_one_person_makes_an_unusable_dataset_and_process_says_why(data, one_person):
    code, out, err = one_person
    key = _dataset_of(data, "solo")
    assert code == EXIT_BAD_INPUT
    (line,) = _errors(err)
    assert re.fullmatch(
        rf"ringside: error: dataset {key} of solo: unusable: one fighter only: no opponent was "
        r"lifted for dataset\.min_clip_s without a break, only the adversary \(\d+\.\d s\); "
        r"training needs footage of two people fighting \(the pose stage's notes say whether a "
        r"second person was found\)",
        line,
    ), line
    # Nothing computed is lost: every stage's output, the dataset and its members are stored.
    video = query(data, "SELECT video_id FROM ingest_adversaries WHERE name = 'solo'")[0][0]
    stages = query(
        data, "SELECT DISTINCT stage FROM stage_outputs WHERE video_id = ? ORDER BY 1", [video]
    )
    assert [s for (s,) in stages] == ["dataset", "ingest", "lift", "pose"]
    assert query(data, "SELECT video_id FROM dataset_members WHERE dataset_key = ?", [key]) == [
        (video,)
    ]
    # The per-video summary says it too, for a video whose adversary has other footage.
    assert "note: dataset" in out and "this video alone cannot be trained on: one fighter" in out


def test_an_adversary_never_lifted_makes_an_unusable_dataset(data, never_lifted):
    code, out, err = never_lifted
    key = _dataset_of(data, "A")
    ((video, output),) = query(
        data, "SELECT video_id, key FROM dataset_members WHERE dataset_key = ?", [key]
    )
    with connect(data / "ringside.duckdb", read_only=True) as con:
        lift = upstream_lift_key(con, video, output)
    roles = query(data, "SELECT DISTINCT role FROM lift_motion WHERE key = ?", [lift])
    assert roles == [("opponent",)], roles
    assert code == EXIT_BAD_INPUT
    (line,) = _errors(err)
    assert line.startswith(
        f"ringside: error: dataset {key} of A: unusable: no adversary frames: the adversary was "
        "never lifted for dataset.min_clip_s without a break, only the opponent ("
    ), line
    assert "frames_rejected_*" in line and "ringside pick" in line


def test_datasets_and_status_show_each_verdict(capsys, data, one_person, never_lifted):
    code, out, _ = run_cli(capsys, "--data", str(data), "datasets", "--json")
    assert code == 0
    rows = json.loads(out)
    # The sample's own dataset stays usable next to the two new ones.
    assert {(r["adversary"], r["unusable"] is None) for r in rows} == {
        ("A", True),
        ("A", False),
        ("solo", False),
    }
    code, out, _ = run_cli(capsys, "--data", str(data), "datasets")
    assert code == 0 and out.splitlines()[0].split()[-1] == "verdict"
    for r in rows:
        (line,) = [line for line in out.splitlines() if line.startswith(r["dataset_key"])]
        said = "usable" if r["unusable"] is None else f"unusable: {r['unusable']}"
        assert line.rstrip().endswith(said), line
    code, out, _ = run_cli(capsys, "--data", str(data), "status")
    assert code == 0
    solo = _dataset_of(data, "solo")
    said = [line for line in out.splitlines() if line.startswith(f"dataset {solo[:12]} of solo")]
    assert said == [f"dataset {solo[:12]} of solo: unusable: {_unusable(data, solo)}"]


def _unusable(data: Path, key: str) -> str:
    with connect(data / "ringside.duckdb", read_only=True) as con:
        return dataset_verdicts(con)[key]


def test_train_names_the_real_cause(capsys, data, one_person):
    key = _dataset_of(data, "solo")
    code, _, err = run_cli(capsys, "--data", str(data), "train", "--dataset", key[:12])
    assert code == EXIT_BAD_INPUT
    assert _errors(err) == [
        f"ringside: error: dataset {key}: cannot be trained on: {_unusable(data, key)}"
    ]
    assert "one fighter only" in err and "lower" not in err


def test_the_dataset_page_says_why_a_dataset_is_unusable(monkeypatch, data, one_person):
    from streamlit.testing.v1 import AppTest

    monkeypatch.setenv("RINGSIDE_DATA", str(data))
    solo = _dataset_of(data, "solo")
    usable = query(data, "SELECT dataset_key FROM datasets ORDER BY created_at LIMIT 1")[0][0]
    for key, errors in ((solo, [f"Unusable for training: {_unusable(data, solo)}"]), (usable, [])):
        app = AppTest.from_function(render_page, args=("dataset",), default_timeout=60)
        app.query_params["dataset"] = key  # the page's link to one dataset
        app.run()
        assert not app.exception, app.exception
        assert app.selectbox[0].value == key
        assert [e.value for e in app.error] == errors


def test_the_sample_stays_usable(capsys, sample_run):
    code, out, _ = run_cli(capsys, "--data", str(sample_run), "datasets", "--json")
    assert code == 0
    (first,) = query(sample_run, "SELECT dataset_key FROM datasets ORDER BY created_at LIMIT 1")[0]
    (sample,) = [r for r in json.loads(out) if r["dataset_key"] == first]
    assert sample["unusable"] is None and sample["transitions"] > 0
