"""Cache store: shard-aligned writes, NaN refusal, done-marks, readable by other readers."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import zarr

from schemas.cache_layout import (
    CELL_BLOCK,
    GridSpec,
    GroupAttrs,
    latent_array,
    packet_arrays,
)
from store.cache_io import read_views, start_row_reads, write_views
from store.cache_store import (
    array_dir,
    ensure_array,
    ensure_group,
    open_root,
    write_packed,
    write_region,
)
from store.raw_shard import CHUNK_ALIGN, MISSING, chunk_stride
from store.shard_layout import index_pairs
from store.shard_writer import ShardWriter, raw_block

GRID = GridSpec(28, 42)


def _group(tmp_path: Path, n: int = 10, shard: int = 4) -> zarr.Group:
    root = open_root(tmp_path / "cache.zarr")
    return ensure_group(root, GroupAttrs("rec", "front", n, GRID.image_h, GRID.image_w, 14, shard))


BIG = GridSpec(14 * 8, 14 * 16)  # 128 cells: two chunks of CELL_BLOCK rows per view


def _packed_array(tmp_path: Path, n: int = 10, shard: int = 4) -> zarr.Array:
    """h_cells of a new group of n views with C_u = 5."""
    root = open_root(tmp_path / "cache.zarr")
    group = ensure_group(root, GroupAttrs("rec", "front", n, BIG.image_h, BIG.image_w, 14, shard))
    return ensure_array(group, packet_arrays(BIG, 5, True)[1], n, shard)


def _rows(rng: np.random.Generator, n_rows: list[int], width: int = 5) -> list[np.ndarray]:
    """Packed rows (k, width) per view, k = n_rows[i], values never zero."""
    return [rng.uniform(0.5, 2.0, (k, width)).astype(np.float32) for k in n_rows]


def _dense(rows: list[np.ndarray], cells: int = 128) -> np.ndarray:
    """Whole packed views (len(rows), cells, width): the rows, then zeros, as float16."""
    out = np.zeros((len(rows), cells, rows[0].shape[1]), np.float16)
    for i, r in enumerate(rows):
        out[i, :len(r)] = r
    return out


def test_packed_rows_round_trip_and_only_occupied_blocks_are_stored(tmp_path: Path) -> None:
    assert CELL_BLOCK == 64
    cells = _packed_array(tmp_path)
    n_rows = [0, 1, 64, 65, 128, 3, 0, 0, 127, 2]
    rows = _rows(np.random.default_rng(1), n_rows)
    for start in (0, 4, 8):
        write_packed(cells, start, rows[start:start + 4])
    np.testing.assert_array_equal(cells[:], _dense(rows))  # zarr-python: absent chunks are 0
    futures = start_row_reads(array_dir(cells), [8, 3, 0], [n_rows[i] for i in (8, 3, 0)])
    for f, frame in zip(futures, [8, 3, 0], strict=True):
        np.testing.assert_array_equal(f.result(), rows[frame].astype(np.float16))
    shards = sum(p.stat().st_size for p in (array_dir(cells) / "c").rglob("*") if p.is_file())
    blocks = sum(-(-k // CELL_BLOCK) for k in n_rows)  # 11 of 20 possible
    index = 3 * (4 * 2 * 16 + 4)  # per shard: (offset, nbytes) per chunk + crc32c
    # only the occupied blocks, raw, each with its CRC32C (4 bytes), padded to 64 bytes
    assert shards == blocks * chunk_stride(CELL_BLOCK * 5 * 2 + 4) + index


def test_rewritten_packed_shard_keeps_no_stale_rows(tmp_path: Path) -> None:
    cells = _packed_array(tmp_path)
    rng = np.random.default_rng(2)
    write_packed(cells, 4, _rows(rng, [128, 128, 128, 128]))
    again = _rows(rng, [3, 0, 70, 1])
    write_packed(cells, 4, again)  # e.g. a rerun with another encoder config
    np.testing.assert_array_equal(cells[4:8], _dense(again))


def test_packed_rows_refusals(tmp_path: Path) -> None:
    cells = _packed_array(tmp_path)
    rng = np.random.default_rng(3)
    nan = _rows(rng, [5, 5, 5, 5])
    nan[2][4, 0] = np.nan
    with pytest.raises(ValueError, match="NaN or Inf"):
        write_packed(cells, 0, nan)
    with pytest.raises(ValueError, match=r"view 3: rows \(129, 5\) do not fit"):
        write_packed(cells, 0, _rows(rng, [5, 5, 5, 129]))
    with pytest.raises(ValueError, match=r"view 1: rows \(5, 4\) do not fit"):
        write_packed(cells, 0, [*_rows(rng, [5]), *_rows(rng, [5], width=4), *_rows(rng, [5, 5])])
    with pytest.raises(ValueError, match="not aligned"):
        write_packed(cells, 2, _rows(rng, [5, 5, 5, 5]))
    assert not np.any(cells[:])


def _stored_chunks(shard: Path, n_chunks: int) -> tuple[list[bytes | None], list[int]]:
    """The stored bytes (data and CRC32C) of each inner chunk of a shard file, None where
    missing, found through its index; and the stored chunks' offsets."""
    raw = shard.read_bytes()
    index = index_pairs(raw, n_chunks)
    chunks = [None if o == MISSING else raw[int(o):int(o) + int(n)] for o, n in index]
    return chunks, [int(o) for o, _ in index if o != MISSING]


def _same_chunks_as_tensorstore(ours: Path, theirs: Path, n_chunks: int) -> None:
    """Both shard files store the same chunks (bytes with their CRC32C) at the same grid
    positions; ours start each at a multiple of CHUNK_ALIGN bytes."""
    mine, offsets = _stored_chunks(ours, n_chunks)
    assert mine == _stored_chunks(theirs, n_chunks)[0]
    assert offsets and all(o % CHUNK_ALIGN == 0 for o in offsets)


def test_raw_shards_hold_tensorstores_chunks_and_are_readable(tmp_path: Path) -> None:
    """The one-pass writer of raw arrays stores tensorstore's chunks, full and short shards;
    tensorstore and zarr-python read them back."""
    group = _group(tmp_path, n=10, shard=4)
    spec = latent_array(GRID, 5, "float16")
    ours = ensure_array(group, spec, 10, 4)
    theirs = ensure_array(group, replace(spec, name="by_tensorstore"), 10, 4)
    assert raw_block(ours) == 5  # one chunk per view: the block is the whole first axis
    assert raw_block(ensure_array(group, packet_arrays(GRID, 7, False)[0], 10, 4)) is None
    x = np.random.default_rng(4).normal(size=ours.shape).astype(np.float16)
    for start in (0, 4, 8):  # the last shard holds 2 of 4 views
        write_region(ours, start, x[start:start + 4])
        write_views(array_dir(theirs), start, x[start:start + 4])
    for shard in range(3):
        key = ours.metadata.encode_chunk_key((shard, 0, 0, 0))
        _same_chunks_as_tensorstore(array_dir(ours) / key, array_dir(theirs) / key, 4)
    np.testing.assert_array_equal(ours[:], x)  # zarr-python
    np.testing.assert_array_equal(read_views(array_dir(ours), [9, 2, 4]), x[[9, 2, 4]])
    assert not list(array_dir(ours).rglob("*.tmp"))


def test_packed_shards_hold_tensorstores_chunks(tmp_path: Path) -> None:
    """Packed rows written by m3gd store the chunks of tensorstore's shard of the same
    per-view writes; tensorstore reads m3gd's shard back."""
    import tensorstore as ts

    cells = _packed_array(tmp_path)
    group = zarr.open_group(str(tmp_path / "cache.zarr"), mode="r+")["rec/front"]
    theirs = ensure_array(group, replace(packet_arrays(BIG, 5, True)[1], name="by_ts"), 10, 4)
    rows = _rows(np.random.default_rng(5), [0, 1, 64, 65, 128, 3, 0, 0, 127, 2])
    write_packed(cells, 0, rows[:4])
    write_packed(cells, 4, rows[4:8])
    handle = ts.open({"driver": "zarr3", "kvstore": {"driver": "file",
                                                     "path": str(array_dir(theirs))}}).result()
    txn = ts.Transaction()
    for i, r in enumerate(rows[:8]):
        if len(r):
            handle.with_transaction(txn)[i, :len(r)].write(r.astype(np.float16)).result()
    txn.commit_async().result()
    for shard in range(2):
        key = cells.metadata.encode_chunk_key((shard, 0, 0))
        n_chunks = 4 * (cells.shape[1] // cells.metadata.codecs[0].chunk_shape[1])
        _same_chunks_as_tensorstore(array_dir(cells) / key, array_dir(theirs) / key, n_chunks)
    back = ts.open({"driver": "zarr3", "kvstore": {"driver": "file",
                                                   "path": str(array_dir(cells))}}).result()
    for i, r in enumerate(rows[:8]):
        np.testing.assert_array_equal(back[i, :len(r)].read().result(), r.astype(np.float16))


def test_background_writer_finishes_every_write_and_raises_the_first_error(
        tmp_path: Path) -> None:
    group = _group(tmp_path)
    arr = ensure_array(group, latent_array(GRID, 3, "float32"), 10, 4)
    x = np.arange(np.prod(arr.shape), dtype=np.float32).reshape(arr.shape)
    with ShardWriter() as writer:
        for start in (0, 4, 8):
            write_region(arr, start, x[start:start + 4], writer)
    np.testing.assert_array_equal(arr[:], x)  # all written when the block ends

    def fail() -> None:
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"), ShardWriter() as writer:
        writer.submit(fail)
        write_region(arr, 0, x[:4] + 1, writer)
    np.testing.assert_array_equal(arr[:4], x[:4] + 1)  # the write queued after still ran


def test_temporary_file_of_a_killed_writer_is_removed_by_the_rewrite(tmp_path: Path) -> None:
    arr = ensure_array(_group(tmp_path), latent_array(GRID, 3, "float32"), 10, 4)
    key = arr.metadata.encode_chunk_key((1, 0, 0, 0))
    stale = array_dir(arr) / Path(key).parent / f".{Path(key).name}.999999.tmp"
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"half a shard")  # a writer killed before its rename
    write_region(arr, 4, np.ones((4, 3, 2, 3), np.float32))
    assert not stale.exists() and np.all(arr[4:8] == 1)
