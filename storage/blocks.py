"""Every checksum of a DuckDB database file, verified by reading the file itself.

DuckDB checks a block's checksum only when a query reads the block, so damage in space no query
reads (free blocks, metadata not loaded) goes unseen by reading the tables. This reads every
block instead.

The layout, as DuckDB's `SingleFileBlockManager` writes it (storage versions 64-68, those of
1.0 to 1.5, and 999, duckdb 2.0.0's own; checked on files of duckdb 1.4.4, which Ringside
pins and which writes 64, and of 2.0.0, which it pinned before):

- bytes 0-4095: the main header: an 8-byte checksum of its other 4088 bytes, "DUCK", the
  storage version (uint64), 4 flags (uint64; bit 0 of the first: encrypted), ...;
- bytes 4096-8191 and 8192-12287: two database headers, each an 8-byte checksum of its other
  4088 bytes, then uint64s: iteration, meta block, free list, block count, block size, ...
  (DuckDB reads the one with the higher iteration);
- then blocks of the block size (262144 bytes unless the database was made with another), each
  an 8-byte checksum of its other bytes.

All integers are little-endian. The checksum of bytes read as uint64 words ``w`` is
5381 ^ (w[0] * K) ^ (w[1] * K) ^ ... (mod 2**64, K = 0xbf58476d1ce4e5b9); DuckDB hashes a
trailing part of under 8 bytes otherwise, but headers and blocks are whole words.

Every block in the file is verified, free or in use (a damaged free block is named like any
other), and blocks past the header's count too (written since the last checkpoint). What a
checksum cannot see: equal words changed alike, which cancel in pairs (8 aligned zero words
all inverted leave it unchanged), and a block replaced whole by an older version of itself.
The write-ahead log (``<name>.wal``) is another file, not looked at here.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HEADER_SIZE = 4096
HEADERS = 3  # the main header, then the two database headers
CHECKSUM_FACTOR = np.uint64(0xBF58476D1CE4E5B9)
CHECKSUM_SEED = np.uint64(5381)
MAGIC = b"DUCK"
# The storage versions whose layout is the one above; 1.4.4 writes 64, 2.0.0 999.
KNOWN_VERSIONS = frozenset({64, 65, 66, 67, 68, 999})
ENCRYPTED_FLAG = 1
DEFAULT_BLOCK_SIZE = 262144
BLOCK_SIZES = frozenset(1 << n for n in range(14, 19))  # 16 KiB to 256 KiB, as DuckDB allows
# Blocks read at a time: bounds memory (the words and their products) to a few tens of MB.
CHUNK_BYTES = 16 << 20


class UnexpectedLayout(ValueError):
    """The file is not laid out as this module knows DuckDB's files to be, so its checksums
    cannot be verified."""


def checksums(words: np.ndarray) -> np.ndarray:
    """DuckDB's checksum of each row of ``words`` (n, k) uint64: (n,) uint64. The products
    wrap mod 2**64, as DuckDB's do."""
    return np.bitwise_xor.reduce(words * CHECKSUM_FACTOR, axis=1) ^ CHECKSUM_SEED


def failing(chunk: bytes | bytearray | memoryview, size: int) -> np.ndarray:
    """Indices of the ``size``-byte pieces of ``chunk`` (a whole number of them, each an 8-byte
    checksum then what it covers) whose stored checksum is not the one of their bytes."""
    words = np.frombuffer(chunk, dtype="<u8").reshape(-1, size // 8)
    return np.flatnonzero(words[:, 0] != checksums(words[:, 1:]))


def damaged_blocks(path: Path) -> list[int]:
    """Byte offsets of the headers and blocks of the DuckDB database file at ``path`` whose
    checksum fails; [] when every one verifies.

    Raises UnexpectedLayout when the file is not one this module can verify: not a DuckDB
    file, a storage version or block size it does not know, encrypted, neither database header
    sound, or a size that is not the headers and whole blocks.
    """
    size = path.stat().st_size
    with path.open("rb") as file:
        headers = file.read(HEADERS * HEADER_SIZE)
        if len(headers) < HEADERS * HEADER_SIZE or headers[8:12] != MAGIC:
            raise UnexpectedLayout(f"{path} is not a DuckDB database file (no DUCK header)")
        damaged = [int(i) * HEADER_SIZE for i in failing(headers, HEADER_SIZE)]
        block_size = _block_size(path, headers, damaged)
        # Fewer blocks than the header counts is no damage: a checkpoint truncates free blocks
        # at the end of the file after writing the header (seen after a SIGTERM; every table
        # read back).
        blocks, rest = divmod(size - HEADERS * HEADER_SIZE, block_size)
        if rest:
            raise UnexpectedLayout(
                f"{path} is {size} bytes: not its {HEADERS * HEADER_SIZE} bytes of headers and "
                f"whole blocks of {block_size} bytes"
            )
        per_chunk = max(1, CHUNK_BYTES // block_size)
        buffer = bytearray(per_chunk * block_size)
        for first in range(0, blocks, per_chunk):
            read = file.readinto(buffer)
            offset = HEADERS * HEADER_SIZE + first * block_size
            found = failing(memoryview(buffer)[:read], block_size)
            damaged += [offset + int(i) * block_size for i in found]
    return damaged


def _block_size(path: Path, headers: bytes, damaged: list[int]) -> int:
    """The block size of the sound database header with the higher iteration, after checking
    the main header's version and flags."""
    version, flags = _uint64s(headers, 12, 2)
    if version not in KNOWN_VERSIONS:
        raise UnexpectedLayout(f"{path}: storage version {version} is not one this check knows")
    if flags & ENCRYPTED_FLAG:
        raise UnexpectedLayout(f"{path} is encrypted: its blocks' checksums cannot be read")
    sound = [
        _uint64s(headers, start + 8, 6)
        for start in (HEADER_SIZE, 2 * HEADER_SIZE)
        if start not in damaged
    ]
    if not sound:
        raise UnexpectedLayout(f"{path}: neither database header matches its checksum")
    block_size = max(sound)[4] or DEFAULT_BLOCK_SIZE  # 0 in older files: DuckDB's default
    if block_size not in BLOCK_SIZES:
        raise UnexpectedLayout(f"{path}: block size {block_size} is not one DuckDB writes")
    return block_size


def _uint64s(data: bytes, start: int, count: int) -> list[int]:
    return [int(v) for v in np.frombuffer(data, dtype="<u8", count=count, offset=start)]
