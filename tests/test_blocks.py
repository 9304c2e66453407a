"""Every block checksum of the database file: verified against a slow reference, found by
`ringside check` where no table read reaches (free space), refused by `ringside backup`, gone
after `check --repair`."""

from __future__ import annotations

import json
import random
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli

from storage.blocks import (
    HEADER_SIZE,
    HEADERS,
    UnexpectedLayout,
    checksums,
    damaged_blocks,
)
from storage.check import scan
from storage.db import connect
from storage.files import sha256_file

BLOCK_SIZE = 262144  # DuckDB's default, which the database below is made with
START = HEADERS * HEADER_SIZE  # the first block's first byte
FLIPPED = 64  # bytes damaged in each place


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> tuple[Path, list[int]]:
    """A small Ringside database (its migrations applied) with rows of pseudo-random numbers
    in `stage_runs`, and blocks a dropped table left free: (the file, the free blocks' first
    bytes)."""
    db = tmp_path_factory.mktemp("blocks") / "ringside.duckdb"
    with connect(db) as con:
        con.execute(
            "INSERT INTO stage_runs (run_id, video_id, stage, key, state, created_at) "
            "SELECT md5(i::VARCHAR), md5((i // 7)::VARCHAR), 'pose', md5((i // 3)::VARCHAR), "
            "'done', TIMESTAMP '2026-01-01' + i * INTERVAL 1 SECOND FROM range(60000) t(i)"
        )
        con.execute(
            "CREATE TABLE scratch AS SELECT hash(i) AS a, hash(i + 1) / 1e19 AS b "
            "FROM range(400000) t(i)"
        )
        con.execute("CHECKPOINT")
        freed = con.execute(
            "SELECT DISTINCT block_id FROM pragma_storage_info('scratch') WHERE block_id >= 0"
        ).fetchall()
        con.execute("DROP TABLE scratch")
        con.execute("CHECKPOINT")
        free = con.execute("SELECT free_blocks FROM pragma_database_size()").fetchone()[0]
    assert free >= len(freed) >= 3, (free, freed)
    return db, sorted(START + block * BLOCK_SIZE for (block,) in freed)


def flip(path: Path, where: int, rng: random.Random, mask: bytes | None = None) -> bytes:
    """XOR ``FLIPPED`` bytes of the file from byte ``where`` with ``mask`` (by default random
    non-zero bytes: the same pattern everywhere can be invisible, see the last test); the mask,
    which undoes it when given again."""
    mask = mask or bytes(rng.randrange(1, 256) for _ in range(FLIPPED))
    with path.open("r+b") as file:
        file.seek(where)
        original = file.read(FLIPPED)
        file.seek(where)
        file.write(bytes(b ^ m for b, m in zip(original, mask, strict=True)))
    return mask


def block_starts(path: Path) -> list[int]:
    return list(range(START, path.stat().st_size, BLOCK_SIZE))


def named_offsets(problems) -> set[int]:
    """The first bytes of the blocks the problems name (a table read's or the block check's
    words)."""
    found = (re.findall(r"bytes from (\d+)|block at byte (\d+)", p.what) for p in problems)
    return {int(a or b) for matches in found for a, b in matches}


def slow_checksum(body: bytes) -> int:
    """DuckDB's block checksum, word by word in Python integers."""
    result = 5381
    for (word,) in np.frombuffer(body, dtype="<u8").reshape(-1, 1).tolist():
        result ^= (word * 0xBF58476D1CE4E5B9) % 2**64
    return result


def test_checksums_match_a_word_by_word_reference_and_the_stored_ones(made):
    db, _ = made
    rng = np.random.default_rng(0)
    words = rng.integers(0, 2**64, size=(3, 512), dtype=np.uint64)
    assert checksums(words).tolist() == [slow_checksum(row.tobytes()) for row in words]
    data = db.read_bytes()
    for start, size in [(0, HEADER_SIZE), (HEADER_SIZE, HEADER_SIZE), (START, BLOCK_SIZE)]:
        piece = data[start : start + size]
        assert int.from_bytes(piece[:8], "little") == slow_checksum(piece[8:]), start


def test_every_block_of_a_fresh_database_verifies_and_a_flip_fails_exactly_its_block(
    made, tmp_path
):
    db, _ = made
    assert damaged_blocks(db) == []
    copy = tmp_path / "copy.duckdb"
    shutil.copyfile(db, copy)
    rng = random.Random(1)
    # Past the main header's magic, version and flags, which are checked before any checksum.
    starts = [(0, 60), (HEADER_SIZE, 8), (2 * HEADER_SIZE, 8)]
    starts += [(start, 0) for start in block_starts(db)]
    for start, skip in starts:
        size = HEADER_SIZE if start < START else BLOCK_SIZE
        where = start + rng.randrange(skip, size - FLIPPED)
        mask = flip(copy, where, rng)
        assert damaged_blocks(copy) == [start], where
        flip(copy, where, rng, mask)  # back as it was
    assert damaged_blocks(copy) == []


def test_a_file_laid_out_otherwise_is_refused_not_guessed(made, tmp_path):
    db, _ = made
    cut = tmp_path / "cut.duckdb"
    cut.write_bytes(db.read_bytes()[: START + BLOCK_SIZE + 100])
    with pytest.raises(UnexpectedLayout, match="whole blocks"):
        damaged_blocks(cut)
    other = tmp_path / "other.duckdb"
    other.write_bytes(b"\0" * (START + BLOCK_SIZE))
    with pytest.raises(UnexpectedLayout, match="not a DuckDB database file"):
        damaged_blocks(other)
    newer = tmp_path / "newer.duckdb"
    data = bytearray(db.read_bytes())
    data[12:20] = (1000).to_bytes(8, "little")
    newer.write_bytes(bytes(data))
    with pytest.raises(UnexpectedLayout, match="storage version 1000"):
        damaged_blocks(newer)


def test_check_finds_64_flipped_bytes_in_each_of_10_random_places(made, tmp_path):
    """Each place damaged in a copy of its own: damage that stops the file from opening would
    hide the other places (`check` then says only that it cannot be opened)."""
    db, free = made
    rng = random.Random(34)
    used = [start for start in block_starts(db) if start not in free]
    places = rng.sample(free, 3) + rng.sample(used, 7)
    for n, start in enumerate(places):
        copy = tmp_path / f"place-{n}.duckdb"
        shutil.copyfile(db, copy)
        flip(copy, start + rng.randrange(0, BLOCK_SIZE - FLIPPED), rng)
        problems = scan(copy, None)
        assert start in named_offsets(problems), (start, [p.what for p in problems])
        assert len(problems) == len(named_offsets(problems)), problems  # each block named once


def test_backup_refuses_a_database_with_a_damaged_block_and_keeps_the_last_backup(
    made, tmp_path, capsys
):
    db, free = made
    data = tmp_path / "data"
    data.mkdir()
    shutil.copyfile(db, data / "ringside.duckdb")
    out = tmp_path / "backup"
    code, _, err = run_cli(capsys, "--data", str(data), "backup", str(out))
    assert code == 0, err
    before = json.loads((out / "backup.json").read_text())

    flip(data / "ringside.duckdb", free[0] + 1000, random.Random(2))  # no table read reaches it
    code, out_text, err = run_cli(capsys, "--data", str(data), "backup", str(out))
    assert code != 0 and not out_text, out_text
    assert len(err.strip().splitlines()) == 1 and err.startswith("ringside: error:"), err
    assert f"block at byte {free[0]}" in err, err
    assert sorted(p.name for p in out.iterdir()) == ["backup.json", "ringside.duckdb"]
    assert json.loads((out / "backup.json").read_text()) == before
    assert sha256_file(out / "ringside.duckdb") == before["sha256"]


def test_repair_drops_a_damaged_free_block(made, tmp_path, capsys):
    db, free = made
    data = tmp_path / "data"
    data.mkdir()
    damaged = data / "ringside.duckdb"
    shutil.copyfile(db, damaged)
    flip(damaged, free[-1] + 5000, random.Random(3))
    check = ["--data", str(data), "check"]

    code, out, _ = run_cli(capsys, *check)
    assert code == 1 and f"block at byte {free[-1]} of ringside.duckdb fails" in out, out
    code, out, _ = run_cli(capsys, *check, "--repair")
    assert code == 0, out
    assert damaged_blocks(damaged) == []
    assert run_cli(capsys, *check)[0] == 0
    with connect(db, read_only=True) as con:
        rows = con.execute("SELECT * FROM stage_runs ORDER BY ALL").fetchall()
    with connect(damaged, read_only=True) as con:
        assert con.execute("SELECT * FROM stage_runs ORDER BY ALL").fetchall() == rows


def test_equal_words_changed_alike_pass_the_checksum(made, tmp_path):
    """DuckDB's checksum XORs one product per 8-byte word, so equal words cancel in pairs:
    eight aligned zero words all inverted (64 bytes of 0xFF) leave it unchanged. No checksum
    check can find such damage. 1 in 8 random places of 64 inverted bytes is aligned, and
    blocks hold runs of zeros: 124 of 1000 such places passed on the sample's database (random
    non-zero bytes: 0 of 1000)."""
    db, _ = made
    copy = tmp_path / "copy.duckdb"
    shutil.copyfile(db, copy)
    words = np.frombuffer(db.read_bytes(), dtype="<u8")
    runs = np.flatnonzero(np.convolve(words == 0, np.ones(8), "valid") == 8) * 8
    inside = (w for w in runs.tolist() if w >= START)
    where = next(w for w in inside if 8 <= (w - START) % BLOCK_SIZE <= BLOCK_SIZE - FLIPPED)
    flip(copy, where, random.Random(), b"\xff" * FLIPPED)
    assert copy.read_bytes() != db.read_bytes()
    assert damaged_blocks(copy) == []
