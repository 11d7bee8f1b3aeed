"""Index bytes of an uncompressed Zarr v3 shard."""

from __future__ import annotations

import google_crc32c
import numpy as np

from schemas.raw_shard import MISSING, shard_index


def test_index_offsets_sizes_missing_chunks_and_checksum() -> None:
    raw = shard_index([True, False, True, True, False], 100)
    assert len(raw) == 5 * 16 + 4
    index = np.frombuffer(raw[:-4], dtype="<u8").reshape(5, 2)
    np.testing.assert_array_equal(index[[0, 2, 3]], [[0, 100], [100, 100], [200, 100]])
    assert (index[[1, 4]] == MISSING).all()
    assert raw[-4:] == google_crc32c.value(raw[:-4]).to_bytes(4, "little")


def test_index_of_an_empty_shard_marks_every_chunk_missing() -> None:
    assert shard_index([False, False], 8)[:32] == b"\xff" * 32

