"""ShardReader: same values as tensorstore and zarr-python, cached handles, invalidation."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import zarr

from bench.support.cache_floor import drop_page_cache
from schemas.cache_layout import GridSpec, GroupAttrs, image_arrays, latent_array, packet_arrays
from schemas.packed_cells import occupied_cells, pack_rows
from store.cache_io import read_clip, read_views
from store.cache_store import (
    array_dir,
    ensure_array,
    ensure_group,
    open_root,
    write_packed,
    write_region,
)
from store.pread_io import UNSUPPORTED
from store.shard_layout import ArrayMeta, index_pairs
from store.shard_reader import ShardReader

GRID = GridSpec(14 * 8, 14 * 16)  # 128 cells: two CELL_BLOCK chunks of h rows per view
N, SHARD, C, CU = 11, 4, 5, 3  # the last shard is short (3 views)


def _views(seed: int) -> dict[str, np.ndarray]:
    """latents (N, C, H, W) f16, g (N, 6, H, W) f32 with the validity channel, h dense."""
    rng = np.random.default_rng(seed)
    occupied = rng.random((N, 1, 8, 16)) < np.linspace(0, 1, N)[:, None, None, None]
    g = rng.normal(size=(N, 6, 8, 16)).astype(np.float32) * occupied
    g[:, :1] = occupied
    h = np.where(occupied, rng.uniform(0.5, 2, (N, CU, 8, 16)), 0).astype(np.float16)
    return {"latents_l0": rng.normal(size=(N, C, 8, 16)).astype(np.float16), "g": g, "h": h}


def _store(tmp_path: Path, data: dict[str, np.ndarray], shards: list[int]) -> Path:
    """Write shards `shards` of `data` into a new cache group; return the group directory."""
    root = open_root(tmp_path / "cache.zarr")
    group = ensure_group(root, GroupAttrs("rec", "front", N, GRID.image_h, GRID.image_w, 14,
                                          SHARD))
    specs = [latent_array(GRID, C, "float16"), *packet_arrays(GRID, CU, True)]
    arrays = {s.name: ensure_array(group, s, N, SHARD) for s in specs}
    for k in shards:
        part = slice(k * SHARD, min(N, (k + 1) * SHARD))
        write_region(arrays["latents_l0"], part.start, data["latents_l0"][part])
        write_region(arrays["g"], part.start, data["g"][part])
        rows = pack_rows(data["h"][part], occupied_cells(data["g"][part]))
        write_packed(arrays["h_cells"], part.start, rows)
    return array_dir(arrays["g"]).parent


def test_values_match_tensorstore_and_missing_shards_read_zero(tmp_path: Path) -> None:
    data = _views(0)
    group = _store(tmp_path, data, [0, 2])  # shard 1 (views 4..7) never written
    expect = {k: v.copy() for k, v in data.items()}
    for v in expect.values():
        v[4:8] = 0
    plain = ShardReader(prefetch_clips=False, chunk_cache_bytes=0)
    for reader, frames in [(r, f) for r in (ShardReader(), plain)
                           for f in ([0, 1, 2, 3], [10, 3, 9, 0], [5, 8, 10], [7])]:
        got = read_clip(group, ["latents_l0", "g", "h", "h_rows"], frames, reader)
        np.testing.assert_array_equal(got["latents_l0"], expect["latents_l0"][frames])
        np.testing.assert_array_equal(got["g"], expect["g"][frames])
        dense = np.moveaxis(expect["h"][frames], 1, -1)
        np.testing.assert_array_equal(got["h"], dense)
        np.testing.assert_array_equal(got["h_rows"], dense[expect["g"][frames][:, 0] > 0.5])
        for name in ("latents_l0", "g", "h_cells"):  # tensorstore and zarr-python agree
            ts_views = read_views(group / name, frames)
            np.testing.assert_array_equal(reader.read_views(group / name, frames), ts_views)
            zarr_views = zarr.open_array(str(group / name), mode="r")[frames]
            np.testing.assert_array_equal(ts_views, zarr_views)


def test_scalar_views_of_unsharded_arrays(tmp_path: Path) -> None:
    """Per-view scalars (stamp_ns: (N,), chunked by shard, not sharded) read like tensorstore."""
    root = open_root(tmp_path / "cache.zarr")
    group = ensure_group(root, GroupAttrs("rec", "front", N, GRID.image_h, GRID.image_w, 14,
                                          SHARD))
    spec = next(s for s in image_arrays(GRID) if s.name == "stamp_ns")
    arr = ensure_array(group, spec, N, SHARD)
    stamps = np.arange(N, dtype=np.int64) * 1_000_000_007 + 17
    for start in range(0, N, SHARD):
        write_region(arr, start, stamps[start:start + SHARD])
    frames = [0, 5, 10, 3]
    got = ShardReader().read_views(array_dir(arr), frames)
    np.testing.assert_array_equal(got, stamps[frames])
    np.testing.assert_array_equal(got, read_views(array_dir(arr), frames))


def test_handles_and_indexes_are_opened_once(tmp_path: Path) -> None:
    group = _store(tmp_path, _views(1), [0, 1, 2])
    reader = ShardReader()
    for _ in range(5):
        read_clip(group, ["latents_l0", "h_rows"], [4, 5, 6, 7], reader)
    # 3 zarr.json + one shard file each of latents, g and h_cells
    assert reader.opens == 3 + 3
    read_clip(group, ["latents_l0", "h_rows"], [0, 9], reader)  # two more shards per array
    assert reader.opens == 6 + 6
    reader.close()
    read_clip(group, ["latents_l0"], [0], reader)
    assert reader.opens == 13  # reopened after close (metadata stays parsed)


def test_replaced_shard_is_reread(tmp_path: Path) -> None:
    first, second = _views(2), _views(3)
    group = _store(tmp_path, first, [0, 1, 2])
    reader = ShardReader()
    got = read_clip(group, ["latents_l0", "h"], [1, 2], reader)
    np.testing.assert_array_equal(got["latents_l0"], first["latents_l0"][[1, 2]])
    _store(tmp_path, second, [0])  # temp file + rename: a new inode under the same path
    got = read_clip(group, ["latents_l0", "h", "g"], [1, 2], reader)
    np.testing.assert_array_equal(got["latents_l0"], second["latents_l0"][[1, 2]])
    np.testing.assert_array_equal(got["g"], second["g"][[1, 2]])
    np.testing.assert_array_equal(got["h"], np.moveaxis(second["h"][[1, 2]], 1, -1))
    os.remove(group / "latents_l0" / "c" / "0" / "0" / "0" / "0")
    assert not reader.read_views(group / "latents_l0", [1]).any()  # removed: fill value


def test_damaged_index_is_refused_with_the_file(tmp_path: Path) -> None:
    group = _store(tmp_path, _views(4), [0])
    shard = group / "latents_l0" / "c" / "0" / "0" / "0" / "0"
    raw = bytearray(shard.read_bytes())
    raw[-10] ^= 0xFF
    shard.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match=r"latents_l0/c/0/0/0/0: shard index CRC32C"):
        ShardReader().read_views(group / "latents_l0", [0])


def test_unknown_layouts_are_left_to_tensorstore(tmp_path: Path) -> None:
    arr = zarr.create_array(str(tmp_path / "t.zarr"), shape=(6, 4), chunks=(2, 4), dtype="f4",
                            compressors=None, filters=None, fill_value=0)
    meta = ShardReader().meta(tmp_path / "t.zarr")
    assert meta is not None and not meta.sharded  # plain raw chunks: read here
    arr[:] = np.arange(24, dtype=np.float32).reshape(6, 4)
    np.testing.assert_array_equal(ShardReader().read_views(tmp_path / "t.zarr", [5, 0]),
                                  arr[[5, 0]])
    assert ArrayMeta.parse({"shape": [2], "codecs": [{"name": "transpose"}]}) is None
    blosc = zarr.create_array(str(tmp_path / "b.zarr"), shape=(4, 2), chunks=(2, 2), dtype="f4",
                              fill_value=0)  # default compressor (zstd, unsharded): tensorstore
    blosc[:] = 1.0
    assert ShardReader().meta(tmp_path / "b.zarr") is None
    np.testing.assert_array_equal(read_clip(tmp_path, ["b.zarr"], [3])["b.zarr"], np.ones((1, 2)))


def test_cold_reads_prefetch_the_clip_once(tmp_path: Path) -> None:
    data = _views(5)
    group = _store(tmp_path, data, [0, 1, 2])
    reader = ShardReader()
    frames = [2, 5, 6]
    read_clip(group, ["latents_l0", "g"], frames, reader)
    before = reader.misses
    drop_page_cache(group)
    fd = os.open(group / "latents_l0" / "c" / "0" / "0" / "0" / "0", os.O_RDONLY)
    try:
        os.preadv(fd, [bytearray(16)], 0, os.RWF_NOWAIT)
        pytest.skip("this file system keeps the pages (tmpfs?): no cold read possible")
    except BlockingIOError:
        pass
    except OSError as err:
        if err.errno not in UNSUPPORTED:
            raise
        pytest.skip("this file system cannot tell a cold read (no RWF_NOWAIT)")
    finally:
        os.close(fd)
    reader.forget_chunks()
    got = read_clip(group, ["latents_l0", "h_rows"], frames, reader)
    assert reader.misses == before + 1  # one miss per clip: the rest was prefetched
    np.testing.assert_array_equal(got["latents_l0"], data["latents_l0"][frames])
    dense = np.moveaxis(data["h"][frames], 1, -1)
    np.testing.assert_array_equal(got["h_rows"], dense[data["g"][frames][:, 0] > 0.5])


def _back_to_back(group: Path, name: str) -> None:
    """Rewrite every shard of array `name` with its stored chunks back to back (no padding):
    the layout tensorstore writes, and m3gd's caches written before chunks were aligned."""
    from store.raw_shard import MISSING, crc_bytes

    meta = ArrayMeta.parse(json.loads((group / name / "zarr.json").read_text()))
    assert meta is not None
    n = meta.file_views * meta.chunks_per_view
    for shard in (p for p in (group / name / "c").rglob("*") if p.is_file()):
        raw = shard.read_bytes()
        index = index_pairs(raw, n).copy()
        body = bytearray()
        for entry in index:
            if entry[0] != MISSING:
                chunk = raw[int(entry[0]):int(entry[0] + entry[1])]
                entry[0] = len(body)
                body += chunk
        shard.write_bytes(bytes(body) + index.tobytes() + crc_bytes(index.tobytes()))


@pytest.mark.parametrize("verify", ["once", "always", "off"])
def test_chunks_stored_back_to_back_read_the_same(tmp_path: Path, verify: str) -> None:
    """Shards without padding between chunks (tensorstore's layout) read the same values,
    whole views and partly filled h-row chunks, and a flipped data byte is still refused."""
    from store.shard_layout import CorruptChunkError

    data = _views(1)
    group = _store(tmp_path, data, [0, 1, 2])
    frames = [10, 3, 9, 0, 5]
    padded = read_clip(group, ["latents_l0", "g", "h_rows"], frames, ShardReader())
    for name in ("latents_l0", "h_cells"):
        _back_to_back(group, name)
    reader = ShardReader(verify=verify)  # type: ignore[arg-type]
    for _ in range(2):  # the first read checks (unless off), the second may not
        got = read_clip(group, ["latents_l0", "g", "h_rows"], frames, reader)
        for key in padded:
            np.testing.assert_array_equal(got[key], padded[key])
    shard = group / "latents_l0" / "c" / "0" / "0" / "0" / "0"
    raw = bytearray(shard.read_bytes())
    raw[5 * 8 * 16 * 2 + 4 + 3] ^= 1  # view 1's data: right after view 0's chunk and CRC
    shard.write_bytes(bytes(raw))
    if verify != "off":
        with pytest.raises(CorruptChunkError, match="view 1"):
            ShardReader(verify=verify).read_views(group / "latents_l0", [1])  # type: ignore[arg-type]
