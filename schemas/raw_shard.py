"""Bytes of an uncompressed Zarr v3 shard, as pure functions (the format of the spec's
`sharding_indexed` codec with inner codecs [bytes little-endian], index codecs
[bytes little-endian, crc32c] and the index at the end: what zarr-python creates for m3gd's
raw arrays).

Such a shard is its inner chunks' bytes back to back followed by an index of one
(offset, nbytes) uint64 pair per inner chunk (2**64 - 1 twice for a missing chunk) and
the CRC32C of that index. With raw inner chunks a shard's bytes are the chunks' values
in C order, so a writer can stream them from the caller's arrays in one pass;
`pipeline.cache.store` does that for the raw arrays (latents, images, packed h_cells),
byte-identical to tensorstore's shard and faster (docs/benchmarks.md, "Cache"). Compressed
arrays are written by tensorstore.
"""

from __future__ import annotations

from collections.abc import Sequence

import google_crc32c
import numpy as np

MISSING = np.iinfo(np.uint64).max
"""Offset and nbytes of an inner chunk that is not stored (read as the fill value)."""


def shard_index(present: Sequence[bool], chunk_nbytes: int) -> bytes:
    """Index (with its CRC32C) of a shard whose inner chunks, in C order over the shard's
    chunk grid, are stored back to back from offset 0 when `present`, `chunk_nbytes` each,
    and missing otherwise.

    Length: 16 * len(present) + 4 bytes.
    """
    stored = np.asarray(present, dtype=bool)
    index = np.full((len(stored), 2), MISSING, dtype="<u8")
    index[stored, 0] = np.arange(int(stored.sum()), dtype=np.uint64) * np.uint64(chunk_nbytes)
    index[stored, 1] = chunk_nbytes
    raw = index.tobytes()
    crc = int(google_crc32c.value(raw))
    return raw + crc.to_bytes(4, "little")
