"""What a shard reader keeps per open file (`OpenShard`), how a file is identified across
replacements (`file_ident`), and the reader's read and checksum settings."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Literal

from store.pread_io import FsReads

SMALL_CHUNK = 64 << 10
"""Inner chunks up to this many bytes (g: 9 KiB a view; K, poses: a few KiB a shard) are
kept decoded by a reader (LRU, `chunk_cache_bytes` in all): decoding g's zstd was ~10 % of
a clip read. Larger chunks (latents, h rows) are read from the page cache every time."""


Verify = Literal["always", "once", "off"]
"""When a reader checks a chunk's CRC32C: on the first read of each chunk of an opened file
("once", the default: every chunk is checked before its first use, a replaced file again;
later reads of it cost nothing, see docs/benchmarks.md); on every read ("always": ~40 % on a
warm clip read, the CRC runs at about the speed of the copy from the page cache); never
("off": only to measure what the check costs, `m3gd bench cache`)."""


@dataclass
class OpenShard:
    """One open shard (or chunk) file: descriptor, identity, parsed index (sharded), the
    offsets of the chunks whose CRC32C was checked (verify="once"), and what its filesystem
    supports."""

    fd: int
    ident: tuple[int, int, int]
    index: list[tuple[int, int]] | None
    verified: set[int] = field(default_factory=set)
    fs: FsReads = field(default_factory=FsReads)


def file_ident(st: os.stat_result) -> tuple[int, int, int]:
    """(inode, mtime ns, size): changes when a file is replaced by rename or rewritten."""
    return (st.st_ino, st.st_mtime_ns, st.st_size)
