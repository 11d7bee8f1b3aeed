"""Frame checks of compressed chunks: healthy frames pass, damaged sizes are named, and no
frame that passes crashes its decoder."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numcodecs
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.ingest.sources.hf.frames import check_blosc, check_lz4, check_zstd, zstd_content_size
from tests.pipeline.ingest.sources.hf.kit import mission

LIDAR = "hesai_points_undistorted"

BLOSC = [numcodecs.Blosc(cname=c, clevel=lv, shuffle=sh, blocksize=bs)
         for c in ("lz4", "zstd", "blosclz") for lv in (0, 5) for sh in (0, 1, 2)
         for bs in (0, 256)]  # fmt: skip


def _data(n: int, dtype: str, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (rng.normal(size=n) * 100).round(1).astype(dtype)


@pytest.mark.parametrize("codec", BLOSC, ids=repr)
@pytest.mark.parametrize(("n", "dtype"), [(0, "f4"), (1, "u1"), (1000, "f4"), (50_001, "f8"),
                                          (40_000, "i2"), (7, "f4")])
def test_healthy_blosc_frames_pass(codec: numcodecs.Blosc, n: int, dtype: str) -> None:
    data = _data(n, dtype)
    frame = codec.encode(data)
    assert check_blosc(frame, data.nbytes) == ""


def test_blosc_truncation_and_sizes_are_named() -> None:
    data = _data(100_000, "f4")
    frame = numcodecs.Blosc(cname="lz4", clevel=5, shuffle=1).encode(data)
    assert "shorter than the 16-byte blosc header" in check_blosc(frame[:15], data.nbytes)
    assert check_blosc(frame[:16], data.nbytes).startswith(
        f"blosc header says {len(frame)} compressed bytes but the chunk holds 16")
    assert "the array's chunk holds 8" in check_blosc(frame, 8)
    assert check_blosc(frame, None) == ""  # decoded size not known: the rest still checked


def test_blosc_block_offsets_and_splits_are_walked() -> None:
    data = _data(100_000, "f4")
    frame = bytearray(numcodecs.Blosc(cname="lz4", clevel=5, shuffle=1, blocksize=4096)
                      .encode(data))  # fmt: skip
    bad_start = bytearray(frame)
    bad_start[16:20] = (len(frame) + 5).to_bytes(4, "little")
    assert "blosc block 0 starts at" in check_blosc(bytes(bad_start), data.nbytes)
    start = int.from_bytes(frame[16:20], "little")
    bad_split = bytearray(frame)
    bad_split[start:start + 4] = (10**6).to_bytes(4, "little")
    assert "blosc block 0: split of 1000000 bytes" in check_blosc(bytes(bad_split), data.nbytes)


def test_blosc_zero_typesize_or_blocksize_refused() -> None:
    data = _data(10_000, "f4")
    frame = bytearray(numcodecs.Blosc(cname="lz4", clevel=5, shuffle=1).encode(data))
    frame[3] = 0
    assert "typesize 0" in check_blosc(bytes(frame), data.nbytes)


def test_lz4_and_zstd_sizes() -> None:
    data = _data(5000, "f8")
    lz4 = numcodecs.LZ4().encode(data)
    assert check_lz4(lz4, data.nbytes) == "" and "shorter" in check_lz4(lz4[:3], None)
    assert "LZ4 header says 40000 decoded bytes" in check_lz4(lz4, 8)
    z = numcodecs.Zstd(level=1).encode(data)
    assert zstd_content_size(z) == data.nbytes and check_zstd(z, data.nbytes) == ""
    assert "zstd frame says 40000 decoded bytes" in check_zstd(z, 16)
    assert "no zstd frame magic" in check_zstd(b"\0" * 12, None)
    assert "shorter than a zstd frame header" in check_zstd(z[:4], None)


@pytest.mark.parametrize("n", [1, 255, 256, 300, 65_791, 65_792, 70_000])
def test_zstd_content_size_field_widths(n: int) -> None:
    """The 1-, 2- (offset 256), 4-byte size fields, at their boundaries."""
    import zstandard

    frame = zstandard.ZstdCompressor(write_content_size=True).compress(b"x" * n)
    assert zstd_content_size(frame) == n


@settings(max_examples=200, deadline=None)
@given(cut=st.integers(min_value=0, max_value=10**6))
def test_any_truncated_blosc_frame_is_refused(cut: int) -> None:
    frame = _FRAME[:cut % len(_FRAME)]
    assert check_blosc(frame, _NBYTES) != ""


_DATA = _data(60_000, "f4")
_FRAME = numcodecs.Blosc(cname="lz4", clevel=5, shuffle=1).encode(_DATA)
_NBYTES = _DATA.nbytes

_FUZZ = textwrap.dedent("""
    import random, sys
    import numcodecs
    from pipeline.ingest.sources.hf.frames import check_blosc
    frame, nbytes = open(sys.argv[1], "rb").read(), int(sys.argv[2])
    r = random.Random(int(sys.argv[3]))
    if r.random() < 0.5:
        buf = frame[:r.randrange(16, 20_000)]
    else:
        flipped = bytearray(frame)
        for _ in range(r.randint(1, 40)):
            i = r.randrange(min(len(frame), 2000) if r.random() < 0.5 else len(frame))
            flipped[i] ^= 1 << r.randrange(8)
        buf = bytes(flipped)
    if sys.argv[4] == "1" and check_blosc(buf, nbytes):
        print("refused")
        sys.exit(0)
    try:
        numcodecs.Blosc().decode(buf)
        print("decoded")
    except Exception:
        print("error")
""")


def fuzz_decode(chunk: Path, nbytes: int, seed: int, check: bool) -> tuple[int, str]:
    """(exit code, outcome) of decoding one damaged copy of a blosc chunk in a fresh child
    process (c-blosc's first decode in a process is the one that reads past a short buffer),
    checked first or not."""
    proc = subprocess.run([sys.executable, "-c", _FUZZ, str(chunk), str(nbytes), str(seed),
                           "1" if check else "0"], capture_output=True, text=True,
                          timeout=120, check=False)  # fmt: skip
    return proc.returncode, proc.stdout.strip()


def test_damaged_chunks_never_crash_the_decoder(
        tmp_path_factory: pytest.TempPathFactory) -> None:
    """Was: a truncated points chunk made c-blosc read past its buffer (SIGSEGV, the whole
    run lost). Damaged copies of a real chunk (cut, or bits flipped) are checked, then decoded
    if they pass, each in a fresh child process, which must never die of a signal."""
    chunk = mission(tmp_path_factory, "clean", "hf-zarr") / "data" / LIDAR / "points" / "1.0.0"
    meta = json.loads((chunk.parent / ".zarray").read_text())
    nbytes = int(np.prod(meta["chunks"])) * 4
    outcomes = [fuzz_decode(chunk, nbytes, seed, check=True) for seed in range(10)]
    assert all(rc == 0 for rc, _ in outcomes), outcomes
    assert {"refused"} < {out for _, out in outcomes}  # some reached the decoder too
