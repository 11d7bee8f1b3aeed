"""Bytes of an uncompressed Zarr v3 shard, as pure functions (the format of the spec's
`sharding_indexed` codec with inner codecs [bytes little-endian, crc32c], index codecs
[bytes little-endian, crc32c] and the index at the end: what zarr-python creates for m3gd's
raw arrays, cache format 3).

Such a shard is its inner chunks one after another, each its bytes followed by their CRC32C
(4 bytes little-endian, the `crc32c` codec) and zero padding up to the next multiple of
CHUNK_ALIGN bytes, then an index of one (offset, nbytes) uint64 pair
per inner chunk (2**64 - 1 twice for a missing chunk) and the CRC32C of that index. With raw
inner chunks a shard's bytes are the chunks' values in C order (with their CRCs), so a
writer can stream them from the caller's arrays in one pass; `store.cache_store` does
that for the raw arrays (latents, images, packed h_cells), faster than tensorstore
(docs/benchmarks.md, "Cache"); every Zarr reader finds the chunks through the index, so the
padding is invisible to it (tensorstore and zarr-python read the same values, tested).
Compressed arrays are written by tensorstore.
"""

from __future__ import annotations

from collections.abc import Sequence

import crc32c as icrar_crc32c
import google_crc32c
import numpy as np

MISSING = np.iinfo(np.uint64).max
"""Offset and nbytes of an inner chunk that is not stored (read as the fill value)."""


CRC_BYTES = 4
"""Bytes the `crc32c` codec appends to each stored chunk."""


def crc32c(data: bytes | memoryview | np.ndarray, value: int = 0) -> int:
    """CRC32C (Castagnoli) of `data` (any C-contiguous buffer), as the `crc32c` codec
    computes it; `value`: the CRC32C of bytes before `data` (extends it).

    Computed by the `crc32c` package (ICRAR), which releases the GIL over buffers of 32 KiB
    and more: a shard writer's checksums then run beside the caller's packing and NaN/Inf
    guard; google_crc32c (what zarr's codec uses) holds the GIL, and the same writes took
    1.155x as long with it (paired median of 12 alternated rounds, docs/benchmarks.md,
    "Cache", 2026-11-28). Same values (tested against google_crc32c). Where that package has
    no hardware CRC32C (`crc32c.hardware_based` False: its check for the instruction covers
    x86 and Linux on ARM), google_crc32c computes it (`crc32c_google`)."""
    buffer = data.data if isinstance(data, np.ndarray) else data
    if not icrar_crc32c.hardware_based:
        return crc32c_google(buffer, value)
    return int(icrar_crc32c.crc32c(buffer, value))


def crc32c_google(data: bytes | memoryview, value: int = 0) -> int:
    """`crc32c` computed by google_crc32c (holds the GIL; hardware or its own software)."""
    return int(google_crc32c.extend(value, np.frombuffer(data, np.uint8)))


def crc_bytes(data: bytes | memoryview | np.ndarray) -> bytes:
    """The 4 bytes the `crc32c` codec appends to `data` (its CRC32C, little-endian)."""
    return crc32c(data).to_bytes(CRC_BYTES, "little")


def crc_bytes_zero_tail(data: bytes | memoryview | np.ndarray, zeros: memoryview) -> bytes:
    """`crc_bytes(data + zeros)` without joining them: the CRC32C of `data` extended over the
    zero bytes `zeros` (a chunk whose last rows are zero padding, stored as two buffers)."""
    return crc32c(zeros, crc32c(data)).to_bytes(CRC_BYTES, "little")


CHUNK_ALIGN = 64
"""Byte alignment of every stored chunk in a shard m3gd writes. A warm read is a copy out of
the page cache; with chunks back to back (each 4 CRC bytes off a multiple of 64) warm clip
reads took 1.07-1.17x the time of the same values stored without checksums, with aligned
chunks 1.02-1.04x (medians of 10 interleaved passes, two runs; docs/benchmarks.md, "Chunk
checksums"). Costs under 64 bytes a chunk."""


def chunk_stride(stored_nbytes: int) -> int:
    """Bytes from one stored chunk's start to the next one's: `stored_nbytes` (data and
    CRC32C) rounded up to a multiple of CHUNK_ALIGN."""
    return -(-stored_nbytes // CHUNK_ALIGN) * CHUNK_ALIGN


def shard_index(present: Sequence[bool], chunk_nbytes: int) -> bytes:
    """Index (with its CRC32C) of a shard whose inner chunks, in C order over the shard's
    chunk grid, are stored from offset 0 every `chunk_stride(chunk_nbytes)` bytes when
    `present`, `chunk_nbytes` each (as stored: with their CRC32C), and missing otherwise.

    Length: 16 * len(present) + 4 bytes.
    """
    stored = np.asarray(present, dtype=bool)
    index = np.full((len(stored), 2), MISSING, dtype="<u8")
    stride = np.uint64(chunk_stride(chunk_nbytes))
    index[stored, 0] = np.arange(int(stored.sum()), dtype=np.uint64) * stride
    index[stored, 1] = chunk_nbytes
    raw = index.tobytes()
    return raw + crc_bytes(raw)
