"""The shard layout the pread reader reads: regular runs of stored chunks (their bounds
pinned), the CRC32C check of a chunk split in parts."""

from __future__ import annotations

import google_crc32c
import numpy as np

from store.shard_layout import MAX_GAP, MISSING, crc_ok, index_pairs, regular_runs


def test_back_to_back_and_padded_chunks_are_one_run() -> None:
    assert regular_runs([(0, 100), (100, 100), (200, 100)], 100) == [(0, 0, 3, 100)]
    assert regular_runs([(64, 100), (192, 100)], 100) == [(0, 64, 2, 128)]


def test_one_chunk_is_a_run_of_its_own_size() -> None:
    assert regular_runs([(640, 100)], 100) == [(0, 640, 1, 100)]


def test_the_largest_gap_is_inclusive() -> None:
    stride = 100 + MAX_GAP
    assert regular_runs([(0, 100), (stride, 100)], 100) == [(0, 0, 2, stride)]
    assert regular_runs([(0, 100), (stride + 1, 100)], 100) is None


def test_overlapping_uneven_short_or_missing_chunks_are_no_run() -> None:
    assert regular_runs([(0, 100), (99, 100)], 100) is None  # stride below the chunk
    assert regular_runs([(0, 100), (128, 100), (260, 100)], 100) is None  # uneven
    assert regular_runs([(0, 100), (128, 99)], 100) is None  # a short chunk
    assert regular_runs([(0, 100), (MISSING, MISSING)], 100) is None
    assert regular_runs([(MISSING, MISSING)], 100) is None  # the reader fills zeros


def test_crc_of_parts_equals_the_crc_of_their_concatenation() -> None:
    data = np.random.default_rng(0).integers(0, 256, 1000, np.uint8)
    stored = np.frombuffer(int(google_crc32c.value(data)).to_bytes(4, "little"), np.uint8)
    assert crc_ok([data], stored)
    assert crc_ok([data[:1], data[1:400], data[400:]], stored)
    assert not crc_ok([data[:-1]], stored)
    flipped = data.copy()
    flipped[999] ^= 0x80
    assert not crc_ok([flipped], stored)


def test_index_pairs_read_the_end_of_a_shard_or_an_index_alone() -> None:
    from store.raw_shard import shard_index

    index = shard_index([True, False, True], 100)
    want = [[0, 100], [MISSING, MISSING], [128, 100]]
    assert index_pairs(index, 3).tolist() == want
    assert index_pairs(b"chunk bytes before the index" + index, 3).tolist() == want
