"""The dataset stage: clips, transitions, labels and statistics, storage, the demo's dataset."""

from __future__ import annotations

import dataclasses
import json

import mujoco
import numpy as np
import pytest
from conftest import process_argv, query, run_cli

from models.humanoid.boxer import BoneLengths, boxer_mjcf
from models.humanoid.compiled import body_states, humanoid_index, keypoint_positions, velocities
from models.humanoid.kinematics import axis_angle_matrix, matrix_to_quat, quat_to_matrix
from models.humanoid.motion import RATE
from models.humanoid.observations import (
    OPPONENT_BLOCKS,
    SELF_BLOCKS,
    block_slices,
    observation,
    self_observation,
)
from storage.db import connect
from storage.records import OutputRecord, insert_columns, write_output
from tasks.dataset.bridging import gaps, interpolate_qpos
from tasks.dataset.config import DatasetConfig
from tasks.dataset.stage import FighterMotion, build_dataset, cut_clips
from tasks.dataset.store import (
    UnknownDataset,
    count_transitions,
    dataset_info,
    load_transitions,
    member_bones,
    record_dataset,
)
from tasks.deepmimic import clip_path, load_deepmimic, retarget
from tasks.errors import BadInput
from tasks.lift.lifting import detect_contacts
from tasks.lift.store import load_motion

BONES = BoneLengths()


def _motion(assets, name: str, *, turn: float = 0.0, shift=(0.0, 0.0)) -> FighterMotion:
    """A DeepMimic clip on the humanoid, turned about z and moved, as the lift would store it."""
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(BONES))
    qpos = retarget(load_deepmimic(clip_path(assets, name)), BONES, fps=RATE)
    rotation = axis_angle_matrix((0, 0, 1), turn)
    qpos[:, :3] = qpos[:, :3] @ rotation.T + (*shift, 0.0)
    qpos[:, 3:7] = matrix_to_quat(rotation @ quat_to_matrix(qpos[:, 3:7]))
    joints = keypoint_positions(model, qpos)
    return FighterMotion(
        step=np.arange(len(qpos)),
        qpos=qpos,
        qvel=velocities(model, qpos, RATE),
        joints=joints,
        contacts=detect_contacts(joints, fps=RATE),
        bones=BONES,
    )


def _take(motion: FighterMotion, keep: np.ndarray) -> FighterMotion:
    return FighterMotion(
        motion.step[keep],
        motion.qpos[keep],
        motion.qvel[keep],
        motion.joints[keep],
        motion.contacts[keep],
        motion.bones,
    )


@pytest.fixture(scope="module")
def pair(assets) -> dict[str, FighterMotion]:
    """The punch clip's boxer facing the walk clip's, 2.5 m apart; the walker lost 5 steps."""
    adversary = _motion(assets, "punch")
    walker = _motion(assets, "walk", turn=np.pi, shift=(2.5, 0.0))
    n = min(len(adversary.step), len(walker.step))
    keep = np.arange(n)
    opponent = _take(walker, keep[(keep < 20) | (keep >= 25)])
    return {"adversary": _take(adversary, keep), "opponent": opponent}


def test_cut_clips_at_gaps_shots_and_the_split():
    steps = np.r_[0:10, 12:30]
    shot = np.where(steps < 20, 0, 1)
    clips = cut_clips(steps, shot, 26, 3, kind="single", role="adversary")
    assert [(c.start, c.end, c.shot, c.split) for c in clips] == [
        (0, 10, 0, "train"),
        (12, 20, 0, "train"),
        (20, 26, 1, "train"),
        (26, 30, 1, "validation"),
    ]
    assert [c.start for c in cut_clips(steps, shot, 26, 5, kind="single", role="a")] == [0, 12, 20]


def test_gaps_bridged_are_short_and_inside_one_shot_and_one_split():
    steps = np.r_[0:10, 12:20, 23:30, 31:40, 42:50]
    shot = np.where(steps < 41, 0, 1)
    # 10-11 (2 steps) is bridged; 20-22 (3) is too long; 30 (1) is; 40-41 crosses a cut...
    assert gaps(steps, shot, 45, 2) == [(10, 12), (30, 31)]
    # ...and a gap across the start of the validation split is never bridged.
    assert gaps(steps, np.zeros_like(steps), 11, 2) == [(30, 31), (40, 42)]
    assert gaps(steps, shot, 45, 0) == []


def test_a_bridge_interpolates_root_rotation_and_hinges():
    before, after = np.zeros(35), np.zeros(35)
    before[3], after[3:7] = 1.0, (np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4))  # 0, 90 deg
    after[:3], after[7:] = (0.3, 0.0, 0.9), 0.6
    middle = interpolate_qpos(before, after, 2)
    np.testing.assert_allclose(middle[:, :3], [[0.1, 0.0, 0.3], [0.2, 0.0, 0.6]])
    np.testing.assert_allclose(middle[:, 7:], np.repeat([[0.2], [0.4]], 28, axis=1))
    angles = 2 * np.degrees(np.arctan2(middle[:, 6], middle[:, 3]))  # about z
    np.testing.assert_allclose(angles, [30.0, 60.0])


def test_two_lost_steps_are_bridged_not_cut(pair, assets):
    """The walker of `pair` losing 2 steps (20, 21) instead of 5: its clip and the interaction
    stay whole, over steps filled between its steps 19 and 22; without bridging (0) they are
    cut in two as at 5."""
    walker = _motion(assets, "walk", turn=np.pi, shift=(2.5, 0.0))
    n = len(pair["adversary"].step)
    keep = np.arange(n)
    fighters = {
        "adversary": pair["adversary"],
        "opponent": _take(walker, (keep < 20) | (keep >= 22)),
    }
    config = DatasetConfig(min_clip_s=0.2, validation_fraction=0.2)
    shots = [(0, 0, 2 * n)]
    out = build_dataset(fighters, shots=shots, fps=2 * RATE, config=config)
    validation_from = int(np.ceil(n * 0.8))
    spans = [
        (c.kind, c.role, c.start_step, c.end_step)
        for c in out.rows["dataset_clips"]
        if c.split == "train"
    ]
    assert ("single", "opponent", 0, validation_from) in spans
    assert ("interaction", None, 0, validation_from) in spans
    assert out.metrics["steps_bridged"] == 2
    # What fills the gap lies within a few cm of the walk it stands in for.
    t = out.rows["dataset_transitions"]
    mine = (t["kind"] == "single") & (t["agent"] == 1) & np.isin(t["step"], [20, 21])
    truth = _take(walker, np.isin(keep, [20, 21]))
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(BONES))
    want = self_observation(body_states(model, truth.qpos, truth.qvel, humanoid_index(model)))
    root_height = want[:, 0]
    np.testing.assert_allclose(np.stack(t["self"][mine])[:, 0], root_height, atol=0.02)

    unbridged = dataclasses.replace(config, max_bridge_steps=0)
    out = build_dataset(fighters, shots=shots, fps=2 * RATE, config=unbridged)
    spans = [(c.kind, c.role, c.start_step, c.end_step) for c in out.rows["dataset_clips"]]
    assert ("single", "opponent", 0, 20) in spans and out.metrics["steps_bridged"] == 0


def test_build_dataset_on_two_deepmimic_fighters(pair):
    frames = int(pair["adversary"].step[-1]) + 1
    config = DatasetConfig(min_clip_s=0.2, validation_fraction=0.2)
    out = build_dataset(pair, shots=[(0, 0, 2 * frames)], fps=2 * RATE, config=config)
    clips = out.rows["dataset_clips"]
    spans = {(c.kind, c.role): [] for c in clips}
    for c in clips:
        spans[(c.kind, c.role)].append((c.start_step, c.end_step, c.split))
    validation_from = int(np.ceil(frames * 0.8))
    # The walker's 5 lost steps cut its clip and the interaction; the split cuts every run.
    assert spans[("single", "adversary")] == [
        (0, validation_from, "train"),
        (validation_from, frames, "validation"),
    ]
    expected_pieces = [(0, 20, "train"), (25, validation_from, "train")]
    expected_pieces.append((validation_from, frames, "validation"))
    assert spans[("single", "opponent")] == expected_pieces
    assert spans[("interaction", None)] == expected_pieces

    t = out.rows["dataset_transitions"]
    single = sum(e - s - 1 for s, e, _ in spans[("single", "adversary")] + expected_pieces)
    assert len(t["step"]) == single + 2 * sum(e - s - 1 for s, e, _ in expected_pieces)
    assert out.metrics["transitions"] == len(t["step"])
    assert out.metrics["clips_interaction"] == 3 and out.metrics["clips_single"] == 5

    # A row is exactly the shared observation function on the two fighters at that step.
    model = mujoco.MjModel.from_xml_string(boxer_mjcf(BONES))
    index = humanoid_index(model)
    states = {r: body_states(model, m.qpos, m.qvel, index) for r, m in pair.items()}
    row = np.flatnonzero((t["kind"] == "interaction") & (t["agent"] == 1) & (t["step"] == 30))[0]
    opp_rows = pair["opponent"].rows(np.array([30, 31]))
    expected = observation(states["opponent"][opp_rows[0]], states["adversary"][30])
    np.testing.assert_allclose(t["self"][row], expected[:223], atol=1e-5)
    np.testing.assert_allclose(t["opp"][row], expected[223:], atol=1e-5)
    np.testing.assert_allclose(
        t["next_self"][row], self_observation(states["opponent"][opp_rows[1]]), atol=1e-5
    )
    single_rows = t["kind"] == "single"
    assert all(o is None for o in t["opp"][single_rows])

    # The punch clip's boxer throws punches at the walker; the walker throws none.
    punches = out.rows["dataset_punches"]
    assert punches and {p.role for p in punches} == {"adversary"}
    assert out.metrics["punches"] == len(punches)
    stats = {(r.role, r.name): r.value for r in out.rows["dataset_statistics"]}
    assert stats[("adversary", "punches_per_min")] > 0
    assert stats[("opponent", "punches_per_min")] == 0
    # Distance is measured where the other fighter is there all clip long: the last clip.
    last = pair["opponent"].rows(np.arange(validation_from, frames))
    gap = pair["adversary"].qpos[validation_from:, :2] - pair["opponent"].qpos[last, :2]
    assert stats[("adversary", "distance_mean_m")] == pytest.approx(
        np.linalg.norm(gap, axis=1).mean()
    )
    assert out.metrics["adversary_punches_per_min"] == stats[("adversary", "punches_per_min")]


def test_no_long_enough_clip_is_a_clear_error(pair):
    with pytest.raises(BadInput, match="dataset.min_clip_s"):
        build_dataset(
            pair,
            shots=[(0, 0, 1000)],
            fps=RATE,
            config=DatasetConfig(min_clip_s=60.0),
        )


def test_transitions_round_trip_through_duckdb(tmp_path, pair):
    out = build_dataset(
        pair,
        shots=[(0, 0, 1000)],
        fps=RATE,
        config=DatasetConfig(min_clip_s=0.2),
    )
    db = tmp_path / "ringside.duckdb"
    record = OutputRecord("dataset", "v1", "k1", {}, "code", {}, "run", 1.0)
    with connect(db) as con:
        write_output(con, record, out.rows, out.metrics)
        key, new = record_dataset(con, "A", DatasetConfig(), [("v1", "k1")])
        assert new and record_dataset(con, "A", DatasetConfig(), [("v1", "k1")]) == (key, False)
    t = out.rows["dataset_transitions"]
    with connect(db, read_only=True) as con:
        got = load_transitions(con, key, kind="interaction", agent=0)
        mine = (t["kind"] == "interaction") & (t["agent"] == 0) & (t["split"] == "train")
        want = np.concatenate([t["self"][mine], np.stack(t["opp"][mine])], axis=1)
        np.testing.assert_array_equal(got.obs, want)
        np.testing.assert_array_equal(got.next_self, t["next_self"][mine])
        motion = load_transitions(con, key, kind="single", split="validation")
        assert motion.obs.shape[1] == 223
        assert len(motion) == int(((t["kind"] == "single") & (t["split"] == "validation")).sum())
        assert count_transitions(con, key, kind="single") + len(motion) == int(
            (t["kind"] == "single").sum()
        )
        assert dataset_info(con, key).members == (("v1", "k1"),)
        assert dataset_info(con, key[:8]).dataset_key == key  # a prefix names it too
        with pytest.raises(UnknownDataset, match="no dataset 'nope'; known: " + key):
            load_transitions(con, "nope", kind="single")
        with pytest.raises(ValueError, match="agent 0 or 1"):
            load_transitions(con, key, kind="interaction", agent=2)


def _dataset_keys(capsys, data) -> list[str]:
    code, out, _ = run_cli(capsys, "--data", str(data), "datasets", "--json")
    assert code == 0
    return [r["dataset_key"] for r in json.loads(out)]


def test_demo_dataset_tables_metrics_and_key(capsys, sample_run, sample_video):
    tables = ["dataset_clips", "dataset_transitions", "dataset_statistics", "datasets"]
    counts = {t: query(sample_run, f"SELECT count(*) FROM {t}")[0][0] for t in tables}
    assert all(counts.values()), counts
    code, out, _ = run_cli(
        capsys, "--data", str(sample_run), "metrics", "--stage", "dataset", "--json"
    )
    assert code == 0
    metrics = {m["name"]: m["value"] for m in json.loads(out)}
    for name in ("clips_single", "clips_interaction", "transitions", "punches"):
        assert name in metrics
    assert (
        metrics["transitions"]
        == query(
            sample_run,
            "SELECT count(*) FROM dataset_transitions t JOIN stage_outputs o "
            "ON o.stage = 'dataset' AND o.key = t.key AND o.video_id = t.video_id",
        )[0][0]
    )
    assert "adversary_guard_height_mean_m" in metrics
    keys = _dataset_keys(capsys, sample_run)

    # Nothing changed: the same dataset key, nothing recomputed.
    base = process_argv(sample_run, sample_video)
    outputs = query(sample_run, "SELECT count(*) FROM stage_outputs WHERE stage = 'dataset'")
    code, out, _ = run_cli(capsys, *base, "--ingest-chunk-frames", "30", "--json")
    assert code == 0
    summary = {r["stage"]: r for r in json.loads(out)}
    assert summary["dataset"]["state"] == "cached"
    assert summary["dataset-assemble"]["key"] == keys[0]
    assert _dataset_keys(capsys, sample_run) == keys
    assert query(sample_run, "SELECT count(*) FROM stage_outputs WHERE stage = 'dataset'") == (
        outputs
    )

    # A dataset setting changes the dataset (and only it): a new key, the lift is reused.
    code, out, _ = run_cli(
        capsys, *base, "--ingest-chunk-frames", "30", "--dataset-min-clip-s", "0.5", "--json"
    )
    assert code == 0
    summary = {r["stage"]: r for r in json.loads(out)}
    assert summary["lift"]["state"] == "cached" and summary["dataset"]["state"] == "done"
    new_key = summary["dataset-assemble"]["key"]
    assert new_key != keys[0] and set(_dataset_keys(capsys, sample_run)) == {new_key, keys[0]}


def test_every_transition_is_one_a_boxer_can_make(sample_run):
    """Bounds no boxer exceeds, on every transition of every dataset of the sample's run: the
    lift's gates (tasks/lift/gates.py) keep anything else out of the dataset."""
    rows = query(sample_run, "SELECT self, opp, next_self FROM dataset_transitions")
    assert rows
    own = block_slices(SELF_BLOCKS)
    theirs = block_slices(OPPONENT_BLOCKS)
    pelvis_velocity = slice(
        own["body_linear_velocities"].start, own["body_linear_velocities"].start + 3
    )
    for self_obs, opp, next_self in rows:
        for obs in (np.asarray(self_obs), np.asarray(next_self)):
            assert 0.4 < obs[own["root_height"]][0] < 1.4  # pelvis height, metres
            assert np.linalg.norm(obs[pelvis_velocity]) < 8.0  # lift.gates.max_root_speed_m_s
        if opp is not None:
            assert np.linalg.norm(np.asarray(opp)[theirs["root_position"]]) < 10.0


def test_extra_single_actor_clips_join_the_dataset(capsys, sample_run, sample_video, assets):
    base = process_argv(sample_run, sample_video)
    base += ["--ingest-chunk-frames", "30", "--json"]
    folder = assets / "dev" / "motions"
    code, out, _ = run_cli(capsys, *base, "--dataset-extra-clips", str(folder))
    assert code == 0
    key = {r["stage"]: r for r in json.loads(out)}["dataset-assemble"]["key"]
    lengths = [len(retarget(load_deepmimic(p))) for p in sorted(folder.glob("*.txt"))]
    with connect(sample_run / "ringside.duckdb", read_only=True) as con:
        extra = load_transitions(con, key, kind="single", agent=2)
        members = dataset_info(con, key).members
        bones = member_bones(con, [m for m in members if not m[0].startswith("extra-")])
        assert len(members) == 2 and len(bones) == 2  # the sample's two fighters
        # Every clip on each fighter's own body: its standing root height is that body's.
        assert len(extra) == len(bones) * sum(n - 1 for n in lengths)
        first = extra.obs[: lengths[0] - 1, 0]  # root height (o^self's first number)
        second = extra.obs[sum(n - 1 for n in lengths) :][: lengths[0] - 1, 0]
        assert abs(np.median(first) - np.median(second)) > 0.005
        assert count_transitions(con, key, kind="single", agent=0) > 0

    code, _, err = run_cli(capsys, *base, "--dataset-extra-clips", str(sample_run / "nothing"))
    assert code == 2
    assert "not a folder (dataset.extra_clips)" in err and len(err.strip().splitlines()) == 1


def test_damaged_motion_rows_are_named(tmp_path, pair):
    """A lift row whose numbers were damaged stops the dataset with the video and the step."""
    motion = pair["adversary"]
    db = tmp_path / "ringside.duckdb"
    qpos = motion.qpos.astype(np.float32)
    qpos[7, 3] = np.nan
    with connect(db) as con:
        for name, value in vars(BONES).items():
            con.execute(
                "INSERT INTO lift_bones VALUES ('L', 'v', 'adversary', ?, ?)", [name, value]
            )
        insert_columns(
            con,
            "lift_motion",
            "L",
            "v",
            {
                "role": np.array(["adversary"] * len(motion.step)),
                "step": motion.step,
                "time_s": motion.step / RATE,
                "qpos": qpos,
                "qvel": motion.qvel.astype(np.float32),
                "joints": motion.joints.reshape(-1, 99).astype(np.float32),
                "contact_left": motion.contacts[:, 0],
                "contact_right": motion.contacts[:, 1],
            },
        )
    with (
        connect(db, read_only=True) as con,
        pytest.raises(BadInput, match="not finite at 1 steps from step 7"),
    ):
        load_motion(con, "v", "L")


def test_steps_no_boxer_could_make_never_become_transitions(pair):
    """The dataset stage's own guard: a lift that slipped through its gates (a walker placed
    300 m off for three steps, a punch flung at 40 m/s for two) loses those steps, as gaps;
    the two are short enough to bridge from the steps either side (`dataset.max_bridge_steps`),
    the three are not."""
    far = pair["opponent"].qpos.copy()
    far[30:33, 0] += 300.0
    fast = pair["adversary"].qvel.copy()
    fast[10:12, :3] = [40.0, 0.0, 0.0]
    flawed = {
        "adversary": dataclasses.replace(pair["adversary"], qvel=fast),
        "opponent": dataclasses.replace(pair["opponent"], qpos=far),
    }
    frames = int(pair["adversary"].step[-1]) + 1
    config = DatasetConfig(min_clip_s=0.2, validation_fraction=0.2)
    out = build_dataset(flawed, shots=[(0, 0, 2 * frames)], fps=2 * RATE, config=config)
    # Three steps 300 m apart drop for both fighters, the two fast ones for the adversary.
    assert out.metrics["steps_rejected"] == 3 * 2 + 2
    assert any("8 steps left out as implausible" in note for note in out.notes)
    t = out.rows["dataset_transitions"]
    own, theirs = block_slices(SELF_BLOCKS), block_slices(OPPONENT_BLOCKS)
    velocity = own["body_linear_velocities"].start
    assert np.linalg.norm(t["self"][:, velocity : velocity + 3], axis=1).max() < 8.0
    present = [o for o in t["opp"] if o is not None]
    assert max(np.linalg.norm(o[theirs["root_position"]]) for o in present) < 10.0
    # The walker lost steps 20-24 before: its rows 30-32 are steps 35-37.
    adversary = set(t["step"][t["agent"] == 0].tolist())
    assert not {35, 36, 37} & adversary and {10, 11} <= adversary
    assert out.metrics["steps_bridged"] == 2
