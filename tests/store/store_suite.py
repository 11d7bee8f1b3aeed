"""One contract every cache store passes (zarr's `StoreTests` pattern, STYLE.md item 10).

A backend writes the views of one cache group (latents, g and packed h rows, N views in
shards of SHARD) and reads them back its own way; `StoreTests` holds the contract tests and
each backend's test class subclasses it with a `backend` fixture:

- local: m3gd's writer (`store.cache_store`, raw shards in one pass) and the pread reader
  (`store.shard_reader` through `store.cache_io.read_clip`);
- tensorstore: every array written and read by tensorstore (`store.cache_io`);
- S3: the local writer's files uploaded to a moto server, read through the whole-shard
  mirror (`store.shard_cache`) and the pread reader, as `ClipStream` reads an `s3://` output.
"""

from __future__ import annotations

import itertools
from abc import ABC, abstractmethod
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zarr

from schemas.cache_layout import H_CELLS, GridSpec, GroupAttrs, latent_array, packet_arrays
from schemas.packed_cells import cell_counts, occupied_cells, pack_rows
from store.cache_io import read_clip, read_views, write_views
from store.cache_store import (
    array_dir,
    ensure_array,
    ensure_group,
    open_root,
    write_packed,
    write_region,
)
from store.shard_reader import ShardReader

GRID = GridSpec(14 * 8, 14 * 16)  # 128 cells: two CELL_BLOCK chunks of h rows per view
N, SHARD, C, CU = 11, 4, 5, 3  # three shards, the last one short (3 views)
GROUP = "rec/front"
NAMES = ["latents_l0", "g", "h_rows"]
"""What a clip read asks for: latents, geometry and the packed rows of h (sum k_i, C_u)."""


def views(seed: int = 0) -> dict[str, np.ndarray]:
    """latents (N, C, H, W) f16, g (N, 6, H, W) f32 (validity channel 0: view i occupied with
    probability i / (N - 1)), h (N, C_u, H, W) f16 zero off the occupied cells."""
    rng = np.random.default_rng(seed)
    occupied = rng.random((N, 1, 8, 16)) < np.linspace(0, 1, N)[:, None, None, None]
    g = rng.normal(size=(N, 6, 8, 16)).astype(np.float32) * occupied
    g[:, :1] = occupied
    h = np.where(occupied, rng.uniform(0.5, 2, (N, CU, 8, 16)), 0).astype(np.float16)
    return {"latents_l0": rng.normal(size=(N, C, 8, 16)).astype(np.float16), "g": g, "h": h}


def expected(data: dict[str, np.ndarray], frames: list[int]) -> dict[str, np.ndarray]:
    """What a read of `frames` returns: latents and g stacked, h as packed rows view after
    view; views of shards never written read as zeros (no rows)."""
    rows = pack_rows(data["h"][frames], occupied_cells(data["g"][frames]))
    return {"latents_l0": data["latents_l0"][frames], "g": data["g"][frames],
            "h_rows": np.concatenate(rows)}


def shard_of(frame: int) -> int:
    """Shard index of view `frame`."""
    return frame // SHARD


def blank(data: dict[str, np.ndarray], shards: list[int]) -> dict[str, np.ndarray]:
    """`data` with every view outside `shards` zeroed (what a store holding only them reads)."""
    out = {k: v.copy() for k, v in data.items()}
    for frame in range(N):
        if shard_of(frame) not in shards:
            for v in out.values():
                v[frame] = 0
    return out


def local_group(root: Path) -> tuple[Path, dict[str, zarr.Array[Any]]]:
    """A new cache group under `root` with the three arrays (created by zarr-python)."""
    group = ensure_group(open_root(root / "cache.zarr"),
                         GroupAttrs("rec", "front", N, GRID.image_h, GRID.image_w, 14, SHARD))
    specs = [latent_array(GRID, C, "float16"), *packet_arrays(GRID, CU, True)]
    arrays = {s.name: ensure_array(group, s, N, SHARD) for s in specs}
    return array_dir(arrays["g"]).parent, arrays


def write_m3gd(root: Path, data: dict[str, np.ndarray], shards: list[int]) -> Path:
    """Write shards `shards` of `data` with m3gd's writer; return the group directory."""
    group, arrays = local_group(root)
    for k in shards:
        part = slice(k * SHARD, min(N, (k + 1) * SHARD))
        write_region(arrays["latents_l0"], part.start, data["latents_l0"][part])
        write_region(arrays["g"], part.start, data["g"][part])
        write_packed(arrays[H_CELLS], part.start,
                     pack_rows(data["h"][part], occupied_cells(data["g"][part])))
    return group


def stored_keys(array: Path) -> set[str]:
    """Chunk keys ("c/0/0/0/0", ...) of the objects stored under a local array directory."""
    return {p.relative_to(array).as_posix() for p in (array / "c").rglob("*")
            if p.is_file() and not p.name.startswith(".")}


def flip_byte(raw: bytes, at: int) -> bytes:
    """`raw` with the bits of byte `at` inverted."""
    out = bytearray(raw)
    out[at] ^= 0xFF
    return bytes(out)


DAMAGED_AT = 100
"""A byte inside view 0's latents chunk (its first C * H * W * 2 = 1280 bytes) of shard 0:
every writer starts a shard with its first stored chunk."""


class StoreBackend(ABC):
    """One way to write and read the cache group; `root` is the test's own folder."""

    def __init__(self, root: Path) -> None:
        self.root = root

    @abstractmethod
    def write(self, data: dict[str, np.ndarray], shards: list[int]) -> None:
        """Store shards `shards` of `data` (the other shards stay unwritten)."""

    @abstractmethod
    def read(self, names: list[str], frames: list[int]) -> dict[str, np.ndarray]:
        """Views `frames` of arrays `names` (of `NAMES`), read by a fresh reader."""

    @abstractmethod
    def keys(self, array: str) -> set[str]:
        """The chunk keys stored for `array` ("c/<shard>/0/0/0")."""

    @abstractmethod
    def damage(self, array: str, key: str, at: int) -> None:
        """Invert byte `at` of the stored object `key` of `array`."""


class StoreTests:
    """The contract; subclasses provide a `backend` fixture returning a `StoreBackend`."""

    @pytest.fixture
    def backend(self, tmp_path: Path) -> StoreBackend:
        raise NotImplementedError  # pragma: no cover (every subclass overrides it)

    def test_round_trip(self, backend: StoreBackend) -> None:
        data = views(0)
        backend.write(data, [0, 1, 2])
        frames = list(range(N))
        got, want = backend.read(NAMES, frames), expected(data, frames)
        for name in NAMES:
            assert got[name].dtype == want[name].dtype, name
            np.testing.assert_array_equal(got[name], want[name], err_msg=name)

    def test_partial_reads(self, backend: StoreBackend) -> None:
        """Some views, out of order and across shards, and one array alone."""
        data = views(1)
        backend.write(data, [0, 1, 2])
        frames = [10, 3, 9, 0, 5]
        want = expected(data, frames)
        got = backend.read(NAMES, frames)
        for name in NAMES:
            np.testing.assert_array_equal(got[name], want[name], err_msg=name)
        np.testing.assert_array_equal(backend.read(["g"], [7])["g"], data["g"][[7]])

    def test_missing_shard_reads_the_fill_value(self, backend: StoreBackend) -> None:
        data = views(2)
        backend.write(data, [0, 2])
        frames = [2, 5, 6, 9]  # views 5 and 6: shard 1, never written
        got, want = backend.read(NAMES, frames), expected(blank(data, [0, 2]), frames)
        for name in NAMES:
            np.testing.assert_array_equal(got[name], want[name], err_msg=name)
        assert not got["latents_l0"][1:3].any() and not got["g"][1:3].any()

    def test_missing_array_is_named(self, backend: StoreBackend) -> None:
        backend.write(views(3), [0])
        with pytest.raises((OSError, ValueError), match="not_an_array"):
            backend.read(["not_an_array"], [0])

    def test_listing(self, backend: StoreBackend) -> None:
        backend.write(views(4), [0, 2])
        for array, ndim in (("latents_l0", 4), ("g", 4), (H_CELLS, 3)):  # h_cells (N, H*W, C_u)
            zeros = "/0" * (ndim - 1)
            assert backend.keys(array) == {f"c/0{zeros}", f"c/2{zeros}"}, array

    def test_checksum_damage_is_detected(self, backend: StoreBackend) -> None:
        data = views(5)
        backend.write(data, [0, 1])
        backend.damage("latents_l0", "c/0/0/0/0", DAMAGED_AT)
        with pytest.raises((OSError, ValueError), match=r"(?i)crc32c|checksum"):
            backend.read(["latents_l0"], [0])
        # the undamaged shard still reads
        np.testing.assert_array_equal(backend.read(["latents_l0"], [4])["latents_l0"],
                                      data["latents_l0"][[4]])

    def test_concurrent_readers(self, backend: StoreBackend) -> None:
        """Four readers at once, each its own clips, all read what was written."""
        data = views(6)
        backend.write(data, [0, 1, 2])
        clips = [[(s + k) % N for k in range(3)] for s in range(N)]

        def read_all(offset: int) -> list[dict[str, np.ndarray]]:
            return [backend.read(NAMES, clips[(offset + i) % N]) for i in range(N)]

        with ThreadPoolExecutor(4) as pool:
            results = list(pool.map(read_all, range(4)))
        for offset, got in enumerate(results):
            for i, clip in enumerate(got):
                want = expected(data, clips[(offset + i) % N])
                for name in NAMES:
                    np.testing.assert_array_equal(clip[name], want[name], err_msg=name)


class LocalStore(StoreBackend):
    """m3gd's writer, the pread reader."""

    def write(self, data: dict[str, np.ndarray], shards: list[int]) -> None:
        self.group = write_m3gd(self.root, data, shards)

    def read(self, names: list[str], frames: list[int]) -> dict[str, np.ndarray]:
        with ShardReader() as reader:
            return read_clip(self.group, names, frames, reader)

    def keys(self, array: str) -> set[str]:
        return stored_keys(self.group / array)

    def damage(self, array: str, key: str, at: int) -> None:
        path = self.group / array / key
        path.write_bytes(flip_byte(path.read_bytes(), at))


class TensorstoreStore(LocalStore):
    """Arrays created by zarr-python, every chunk written and read by tensorstore."""

    def write(self, data: dict[str, np.ndarray], shards: list[int]) -> None:
        self.group, _ = local_group(self.root)
        for k in shards:
            part = slice(k * SHARD, min(N, (k + 1) * SHARD))
            write_views(self.group / "latents_l0", part.start, data["latents_l0"][part])
            write_views(self.group / "g", part.start, data["g"][part])
            rows = pack_rows(data["h"][part], occupied_cells(data["g"][part]))
            dense = np.zeros((len(rows), GRID.grid_h * GRID.grid_w, CU), np.float16)
            for i, r in enumerate(rows):
                dense[i, :len(r)] = r
            write_views(self.group / H_CELLS, part.start, dense)

    def read(self, names: list[str], frames: list[int]) -> dict[str, np.ndarray]:
        out = {n: read_views(self.group / n, frames) for n in names if n != "h_rows"}
        if "h_rows" in names:
            counts = cell_counts(occupied_cells(read_views(self.group / "g", frames)))
            cells = read_views(self.group / H_CELLS, frames)
            out["h_rows"] = np.concatenate([c[:k] for c, k in zip(cells, counts, strict=True)])
        return out


class S3Store(LocalStore):
    """The local writer's files on an S3 server; reads through a fresh whole-shard mirror."""

    def __init__(self, root: Path, url: str) -> None:
        super().__init__(root)
        self.url = url
        self.mirrors = itertools.count()

    def write(self, data: dict[str, np.ndarray], shards: list[int]) -> None:
        from tests.s3_fixture import upload

        local = write_m3gd(self.root / "local", data, shards)
        upload(self.root / "local" / "cache.zarr", f"{self.url}/cache.zarr")
        self.group_rel = f"cache.zarr/{local.relative_to(self.root / 'local' / 'cache.zarr')}"

    def read(self, names: list[str], frames: list[int]) -> dict[str, np.ndarray]:
        from store.shard_cache import open_remote

        # a fresh mirror per read: each read goes to the server
        mirror = open_remote(self.url, self.root / f"mirror{next(self.mirrors)}")
        assert mirror is not None
        objects = mirror.view_objects(self.group_rel, names, frames)
        with mirror.holding(objects), ShardReader() as reader:
            return read_clip(mirror.root / self.group_rel, names, frames, reader)

    def keys(self, array: str) -> set[str]:
        import pyarrow.fs as pafs

        from store.object_store import filesystem, parse_url

        base = parse_url(f"{self.url}/{self.group_rel}/{array}").key("")
        found = filesystem().get_file_info(pafs.FileSelector(base, recursive=True))
        rels = [f.path[len(base):].lstrip("/") for f in found if f.type == pafs.FileType.File]
        return {rel for rel in rels if rel.startswith("c/")}

    def damage(self, array: str, key: str, at: int) -> None:
        from store.object_store import filesystem, parse_url

        path = parse_url(f"{self.url}/{self.group_rel}/{array}/{key}").key("")
        fs = filesystem()
        with fs.open_input_stream(path) as f:
            raw = f.read()
        with fs.open_output_stream(path) as out:
            out.write(flip_byte(raw, at))
