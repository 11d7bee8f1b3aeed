"""Checks of a compressed chunk's frame against its length and the array's chunk, before a C
decoder sees it (pure functions over bytes).

c-blosc 1 (numcodecs' `Blosc`) trusts the sizes in its 16-byte header and in each block's
split headers: a truncated chunk, or a flipped byte in those sizes, makes it read past the
buffer, which kills the process (SIGSEGV) instead of raising. Here the whole frame structure is
walked first: header sizes (nbytes = the chunk's decoded size, cbytes = the buffer's length),
the block offsets, and every split's compressed size within the buffer. LZ4 (numcodecs: a
4-byte decoded size, then one block) and zstd (magic, and the frame content size where the
frame carries it) are checked the same way; their decoders bound every read by the buffer
and only need the sizes right. Other codecs (gzip, zlib, bz2) are decoded by Python's own
bounded decoders and are not checked here.

Every check returns '' when the frame is consistent, else what is wrong (one phrase).
"""

from __future__ import annotations

import struct

BLOSC_HEADER = 16
BLOSC_MEMCPYED = 0x02
BLOSC_DONT_SPLIT = 0x10
BLOSC_MAX_SPLITS = 16
BLOSC_MIN_BUFFERSIZE = 128
ZSTD_MAGIC = 0xFD2FB528


def check_blosc(buf: bytes | memoryview, expected: int | None) -> str:
    """Check a c-blosc 1 frame: header sizes against len(buf) and `expected` decoded bytes
    (None: not known), block offsets and every split size within the buffer."""
    size = len(buf)
    if size < BLOSC_HEADER:
        return f"{size} bytes, shorter than the {BLOSC_HEADER}-byte blosc header"
    flags, typesize = buf[2], buf[3]
    nbytes, blocksize, cbytes = struct.unpack_from("<III", buf, 4)
    if cbytes != size:
        return (f"blosc header says {cbytes} compressed bytes but the chunk holds {size} "
                "(truncated or damaged)")  # fmt: skip
    if expected is not None and nbytes != expected:
        return f"blosc header says {nbytes} decoded bytes, the array's chunk holds {expected}"
    if nbytes == 0:
        return ""
    if flags & BLOSC_MEMCPYED:
        ok = cbytes == BLOSC_HEADER + nbytes
        return "" if ok else f"stored blosc chunk of {cbytes} bytes for {nbytes} bytes"
    if typesize == 0 or blocksize == 0 or blocksize > nbytes:
        return f"blosc header: typesize {typesize}, blocksize {blocksize} for {nbytes} bytes"
    return _blosc_blocks(buf, flags, typesize, nbytes, blocksize)


def _blosc_blocks(buf: bytes | memoryview, flags: int, typesize: int, nbytes: int,
                  blocksize: int) -> str:  # fmt: skip
    """Walk every block's splits (c-blosc 1's `blosc_d` split rule) within the buffer."""
    size = len(buf)
    nblocks, leftover = divmod(nbytes, blocksize)
    nblocks += leftover > 0
    first = BLOSC_HEADER + 4 * nblocks
    if first > size:
        return f"{nblocks} blosc block offsets do not fit in {size} bytes"
    starts = struct.unpack_from(f"<{nblocks}i", buf, BLOSC_HEADER)
    for j, start in enumerate(starts):
        last = leftover > 0 and j == nblocks - 1
        bsize = leftover if last else blocksize
        split = (not flags & BLOSC_DONT_SPLIT and typesize <= BLOSC_MAX_SPLITS
                 and blocksize // typesize >= BLOSC_MIN_BUFFERSIZE and not last)
        if not first <= start < size:
            return f"blosc block {j} starts at {start}, outside {first}..{size - 1}"
        pos = start
        for _ in range(typesize if split else 1):
            if pos + 4 > size:
                return f"blosc block {j} runs past the chunk's {size} bytes"
            (csize,) = struct.unpack_from("<i", buf, pos)
            if csize < 0 or pos + 4 + csize > size or csize > bsize:
                return f"blosc block {j}: split of {csize} bytes at {pos} does not fit"
            pos += 4 + csize
    return ""


def check_lz4(buf: bytes | memoryview, expected: int | None) -> str:
    """Check a numcodecs LZ4 frame: its 4-byte decoded size against `expected`."""
    if len(buf) < 4:
        return f"{len(buf)} bytes, shorter than the 4-byte LZ4 size header"
    (nbytes,) = struct.unpack_from("<I", buf, 0)
    if expected is not None and nbytes != expected:
        return f"LZ4 header says {nbytes} decoded bytes, the array's chunk holds {expected}"
    return ""


def zstd_content_size(buf: bytes | memoryview) -> int | str | None:
    """The frame content size a zstd frame header declares (None when absent), or what is
    wrong with the header."""
    if len(buf) < 5:
        return f"{len(buf)} bytes, shorter than a zstd frame header"
    (magic,) = struct.unpack_from("<I", buf, 0)
    if magic != ZSTD_MAGIC:
        return f"no zstd frame magic (found 0x{magic:08x})"
    fhd = buf[4]
    fcs_flag, single, did_flag = fhd >> 6, (fhd >> 5) & 1, fhd & 3
    fcs_len = (1 if single else 0, 2, 4, 8)[fcs_flag]
    pos = 5 + (0 if single else 1) + (0, 1, 2, 4)[did_flag]
    if pos + fcs_len > len(buf):
        return f"zstd frame header runs past the chunk's {len(buf)} bytes"
    if fcs_len == 0:
        return None
    value = int.from_bytes(bytes(buf[pos:pos + fcs_len]), "little")
    return value + 256 if fcs_len == 2 else value


def check_zstd(buf: bytes | memoryview, expected: int | None) -> str:
    """Check a zstd frame: magic, and its content size (where present) against `expected`."""
    got = zstd_content_size(buf)
    if isinstance(got, str):
        return got
    if got is not None and expected is not None and got != expected:
        return f"zstd frame says {got} decoded bytes, the array's chunk holds {expected}"
    return ""


CHECKS = {"blosc": check_blosc, "lz4": check_lz4, "zstd": check_zstd}
"""Frame check by codec id (Zarr v2 `compressor.id`, Zarr v3 codec name without a prefix)."""
