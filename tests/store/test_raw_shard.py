"""Index bytes of an uncompressed Zarr v3 shard."""

from __future__ import annotations

import google_crc32c
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from store.raw_shard import (
    CHUNK_ALIGN,
    MISSING,
    chunk_stride,
    crc32c,
    crc32c_google,
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


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=4096), st.integers(0, 2**32 - 1), st.integers(0, 7))
def test_crc32c_is_zarrs_codec_crc_of_any_bytes(data: bytes, start: int, offset: int) -> None:
    """The writer's CRC32C (the `crc32c` package) equals google_crc32c's, which zarr's `crc32c`
    codec computes: of bytes, of an unaligned memoryview, of an array, and extending a start
    value (empty input included)."""
    want = int(google_crc32c.value(data))
    assert crc32c(data) == want
    assert crc32c(memoryview(b"x" * offset + data)[offset:]) == want
    assert crc32c(np.frombuffer(data, np.uint8)) == want
    assert crc32c(data, start) == int(google_crc32c.extend(start, data))


def test_crc32c_of_a_buffer_past_the_gil_release_size() -> None:
    """Buffers of 32 KiB and more, which the `crc32c` package checksums without the GIL, give
    the same value as google_crc32c (a latent chunk is about 1 MiB)."""
    data = np.random.default_rng(1).integers(0, 256, (1 << 20) + 3, dtype=np.uint8)
    assert crc32c(data) == int(google_crc32c.value(data))
    assert crc_bytes(data[1:]) == int(google_crc32c.value(data[1:])).to_bytes(4, "little")


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=2048), st.integers(0, 2**32 - 1), st.integers(0, 7))
def test_crc32c_without_a_hardware_crc_is_googles(data: bytes, start: int, offset: int) -> None:
    """The path taken where the `crc32c` package has no hardware CRC32C gives the same values."""
    view = memoryview(b"x" * offset + data)[offset:]
    assert crc32c_google(view, start) == crc32c(data, start) == int(
        google_crc32c.extend(start, data))


def test_crc32c_uses_google_where_the_package_has_no_hardware_crc(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """`crc32c.hardware_based` False (a software build): google_crc32c computes the value."""
    import store.raw_shard as raw_shard
    calls: list[int] = []

    def google(data: bytes | memoryview, value: int = 0) -> int:
        calls.append(len(data))
        return crc32c_google(data, value)

    monkeypatch.setattr(raw_shard.icrar_crc32c, "hardware_based", False)
    monkeypatch.setattr(raw_shard, "crc32c_google", google)
    assert raw_shard.crc32c(b"123456789") == 0xE3069283 and calls == [9]  # the check value
