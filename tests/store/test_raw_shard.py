"""Index bytes of an uncompressed Zarr v3 shard."""

from __future__ import annotations

import google_crc32c
import numpy as np

from store.raw_shard import (
    CHUNK_ALIGN,
    MISSING,
    chunk_stride,
    crc_bytes,
    crc_bytes_zero_tail,
    shard_index,
)


def test_index_offsets_sizes_missing_chunks_and_checksum() -> None:
    """Stored chunks of 100 bytes start every 128 bytes (the next multiple of 64)."""
    raw = shard_index([True, False, True, True, False], 100)
    assert len(raw) == 5 * 16 + 4
    index = np.frombuffer(raw[:-4], dtype="<u8").reshape(5, 2)
    np.testing.assert_array_equal(index[[0, 2, 3]], [[0, 100], [128, 100], [256, 100]])
    assert (index[[1, 4]] == MISSING).all()
    assert raw[-4:] == google_crc32c.value(raw[:-4]).to_bytes(4, "little")


def test_index_of_an_empty_shard_marks_every_chunk_missing() -> None:
    assert shard_index([False, False], 8)[:32] == b"\xff" * 32



def test_chunk_stride_rounds_up_to_the_alignment_and_keeps_a_multiple() -> None:
    assert CHUNK_ALIGN == 64
    assert chunk_stride(64) == 64  # already aligned: no padding
    assert chunk_stride(65) == 128
    assert chunk_stride(1) == 64
    assert chunk_stride(1179648 + 4) == 1179648 + 64  # a latents chunk and its CRC32C


def test_index_of_aligned_chunks_has_no_padding() -> None:
    index = np.frombuffer(shard_index([True, True], 128)[:-4], dtype="<u8").reshape(2, 2)
    np.testing.assert_array_equal(index, [[0, 128], [128, 128]])


def test_crc_of_a_zero_tail_is_the_crc_of_the_joined_bytes() -> None:
    """A short chunk's CRC extended over its zero tail equals the CRC of the padded copy."""
    data = np.random.default_rng(0).integers(0, 256, 1000, dtype=np.uint8)
    zeros = memoryview(bytes(500))
    for tail in (0, 1, 300, 500):
        joined = np.concatenate([data, np.zeros(tail, np.uint8)])
        assert crc_bytes_zero_tail(data.data.cast("B"), zeros[:tail]) == crc_bytes(joined)
