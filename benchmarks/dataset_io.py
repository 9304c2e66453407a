"""Dataset storage speed: transitions written to and read from DuckDB, against numpy in memory.

Writes 4 outputs of 25,000 interaction transitions each (o^self 223, o^opp 51 and the next
o^self 223 floats, as the dataset stage stores them; random values, since the speed depends on
the sizes only) with the stage's own writer (`storage.records.write_output`), assembles them
into one dataset (`record_dataset`) and reads agent 0's transitions back with the loader
training uses (`load_transitions`), best of 3. The baseline, in the same run, copies the same
arrays in memory with numpy. Prints both rates and, last,
``duckdb_vs_numpy_read: R x``: DuckDB's read rate over numpy's (1.0 would be as fast as memory).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from models.humanoid.observations import OPPONENT_DIM, SELF_DIM  # noqa: E402
from storage.db import connect  # noqa: E402
from storage.records import OutputRecord, write_output  # noqa: E402
from tasks.dataset.config import DatasetConfig  # noqa: E402
from tasks.dataset.store import load_transitions, record_dataset  # noqa: E402

OUTPUTS, PER_OUTPUT = 4, 25_000


def _columns(rng: np.random.Generator, agent: int, n: int) -> dict[str, np.ndarray]:
    return {
        "kind": np.array(["interaction"] * n),
        "agent": np.full(n, agent, dtype=np.int8),
        "split": np.array(["train"] * n),
        "clip": np.zeros(n, dtype=np.int32),
        "step": np.arange(n, dtype=np.int32),
        "self": rng.standard_normal((n, SELF_DIM), dtype=np.float32),
        "opp": rng.standard_normal((n, OPPONENT_DIM), dtype=np.float32),
        "next_self": rng.standard_normal((n, SELF_DIM), dtype=np.float32),
    }


def _best(fn, repeats: int = 3) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - start)
    return best, out


def main() -> None:
    rng = np.random.default_rng(0)
    half = PER_OUTPUT // 2
    outputs = [
        {
            k: np.concatenate([a, b])
            for (k, a), b in zip(
                _columns(rng, 0, half).items(), _columns(rng, 1, half).values(), strict=True
            )
        }
        for _ in range(OUTPUTS)
    ]
    total = OUTPUTS * PER_OUTPUT
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "bench.duckdb"
        start = time.perf_counter()
        for i, columns in enumerate(outputs):
            record = OutputRecord("dataset", f"video{i}", "k", {}, "bench", {}, "bench", 0.0)
            with connect(db) as con:
                write_output(con, record, {"dataset_transitions": columns}, {})
        write_s = time.perf_counter() - start
        with connect(db) as con:
            key, _ = record_dataset(
                con, "bench", DatasetConfig(), [(f"video{i}", "k") for i in range(OUTPUTS)]
            )
        with connect(db, read_only=True) as con:
            read_s, got = _best(lambda: load_transitions(con, key, kind="interaction", agent=0))
    want_obs = np.concatenate(
        [np.concatenate([c["self"], c["opp"]], 1)[c["agent"] == 0] for c in outputs]
    )
    assert np.array_equal(got.obs, want_obs), "DuckDB returned different transitions"
    read_rows = len(got)

    def numpy_read():
        obs = np.empty((read_rows, SELF_DIM + OPPONENT_DIM), np.float32)
        nxt = np.empty((read_rows, SELF_DIM), np.float32)
        at = 0
        for c in outputs:
            mine = c["agent"] == 0
            n = int(mine.sum())
            obs[at : at + n, :SELF_DIM] = c["self"][mine]
            obs[at : at + n, SELF_DIM:] = c["opp"][mine]
            nxt[at : at + n] = c["next_self"][mine]
            at += n
        return obs

    numpy_s, _ = _best(numpy_read)
    duck_read_rate = read_rows / read_s
    numpy_read_rate = read_rows / numpy_s
    print(f"rows: {total} written ({OUTPUTS} outputs), {read_rows} read (agent 0)")
    print(f"duckdb_write: {total / write_s:,.0f} transitions/s")
    print(f"duckdb_read: {duck_read_rate:,.0f} transitions/s")
    print(f"numpy_read: {numpy_read_rate:,.0f} transitions/s")
    print(f"duckdb_vs_numpy_read: {duck_read_rate / numpy_read_rate:.3f} x")


if __name__ == "__main__":
    main()
