"""SIGKILL at 20 random moments of `ringside process`, each time in a fresh data directory; then
see what is left (tests/kill_rounds.py says what must hold: among others, no process below it
alive 30 s after the kill). Too long for `make test` and CI, it is marked ``slow``: `make test`
leaves it out and `make test-slow` runs it;
`benchmarks/kill_runs.py` runs the same rounds and SIGTERM ones too, and reports them.
"""

from __future__ import annotations

import random
import signal
from dataclasses import asdict

import pytest
from kill_rounds import run, stop_and_rerun
from outputs import stage_contents

KILLS = 20


@pytest.mark.slow
def test_twenty_kills_leave_no_process_no_temporary_file_and_the_same_results(
    tmp_path, sample_video
):
    rng = random.Random(0)
    whole = tmp_path / "whole"
    took = run(whole, sample_video)
    expected = stage_contents(whole)
    rounds = []
    for attempt in range(3 * KILLS):
        if len(rounds) == KILLS:
            break
        data = tmp_path / f"killed-{attempt}"
        at = rng.uniform(1.0, 0.9 * took)
        stopped = stop_and_rerun(data, sample_video, at, signal.SIGKILL, expected)
        if stopped is None:
            continue  # it finished before its moment: no kill, another round
        rounds.append(stopped)
        print(asdict(stopped), flush=True)
    assert len(rounds) == KILLS
    assert [asdict(r) for r in rounds if r.problems] == []
