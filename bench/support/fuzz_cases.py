"""Damage done to a ROS1 bag on purpose: byte flips, truncation, chunk shuffles (pure on bytes).

Each mutation takes the bag's bytes and a seeded generator and returns the damaged bytes and a
one-line description. `chunk_spans` lists the top-level chunk records (with the index-data
records that follow each), read from the intact file's record headers.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from io import BytesIO

import numpy as np
from rosbags.rosbag1.reader import Header, RecordType

_U32 = struct.Struct("<L")
HEAD = 13  # len(b"#ROSBAG V2.0\n")

Mutation = Callable[[bytes, np.random.Generator], tuple[bytes, str]]


def records(data: bytes) -> list[tuple[int, int, int, int]]:
    """(op, start, data start, end) of every top-level record of an intact bag."""
    out, pos = [], HEAD
    while pos + 4 <= len(data):
        hlen = _U32.unpack_from(data, pos)[0]
        header = Header.read(BytesIO(data[pos : pos + 4 + hlen]))
        size = _U32.unpack_from(data, pos + 4 + hlen)[0]
        end = pos + 8 + hlen + size
        out.append((header.get_uint8("op"), pos, pos + 8 + hlen, end))
        pos = end
    return out


def chunk_spans(data: bytes) -> list[tuple[int, int, int]]:
    """(start, data start, end) of each chunk record with the index-data records after it."""
    spans: list[list[int]] = []
    for op, start, data_at, end in records(data):
        if op == RecordType.CHUNK:
            spans.append([start, data_at, end])
        elif op == RecordType.IDXDATA and spans and spans[-1][2] == start:
            spans[-1][2] = end
    return [(a, b, c) for a, b, c in spans]


def flip_bytes(data: bytes, rng: np.random.Generator, n: int | None = None,
               at: int | None = None) -> tuple[bytes, str]:  # fmt: skip
    """XOR `n` (1-64) bytes at random places (or in a 2 kB window from `at`) with 1-255."""
    n = int(rng.integers(1, 65)) if n is None else n
    lo, hi = (HEAD, len(data)) if at is None else (at, min(len(data), at + 2048))
    where = np.sort(rng.integers(lo, hi, n))
    buf = np.frombuffer(data, np.uint8).copy()
    buf[where] ^= rng.integers(1, 256, n, dtype=np.uint8)
    return buf.tobytes(), f"{n} byte(s) flipped in bytes {int(where[0])}-{int(where[-1])}"


def truncate(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """Cut the file at a random byte."""
    keep = int(rng.integers(HEAD, len(data)))
    return data[:keep], f"cut to {keep} of {len(data)} bytes"


def shuffle_chunks(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """Swap two chunk records (each with its index data) in the file; the bag index is stale."""
    spans = chunk_spans(data)
    if len(spans) < 2:
        return flip_bytes(data, rng)
    i, j = sorted(int(k) for k in rng.choice(len(spans), 2, replace=False))
    (a0, _, a1), (b0, _, b1) = spans[i], spans[j]
    out = data[:a0] + data[b0:b1] + data[a1:b0] + data[a0:a1] + data[b1:]
    return out, f"chunks {i} (byte {a0}) and {j} (byte {b0}) swapped"


def flip_first_chunk(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """Flip 30 bytes inside the first chunk's compressed data (the audit's LiDAR case)."""
    spans = chunk_spans(data)
    if not spans:
        return flip_bytes(data, rng)
    _, data_at, _ = spans[0]
    return flip_bytes(data, rng, n=30, at=data_at + 64)


MUTATIONS: dict[str, Mutation] = {
    "flip": flip_bytes,
    "truncate": truncate,
    "shuffle": shuffle_chunks,
    "flip_first_chunk": flip_first_chunk,
}
