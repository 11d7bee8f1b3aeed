"""Cache store: shard-aligned writes, NaN refusal, done-marks, readable by other readers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import zarr

from pipeline.cache.store import (
    array_dir,
    clear_marks,
    ensure_array,
    ensure_group,
    mark_shard_done,
    open_root,
    shard_done,
    write_region,
)
from schemas.cache_io import read_views
from schemas.cache_layout import GridSpec, GroupAttrs, latent_array, packet_arrays, root_attrs
from schemas.versioning import UnknownSchemaVersion

GRID = GridSpec(28, 42)


def _group(tmp_path: Path, n: int = 10, shard: int = 4) -> zarr.Group:
    root = open_root(tmp_path / "cache.zarr")
    return ensure_group(root, GroupAttrs("rec", "front", n, GRID.image_h, GRID.image_w, 14, shard))


def test_round_trip_every_codec(tmp_path: Path) -> None:
    group = _group(tmp_path)
    rng = np.random.default_rng(0)
    for spec in [latent_array(GRID, 5, "float16"), *packet_arrays(GRID, 7, True)]:
        arr = ensure_array(group, spec, 10, 4)
        x = rng.normal(size=arr.shape).astype(spec.dtype)
        x[:, :, 0, :] = 0  # empty cells
        for start in (0, 4, 8):
            write_region(arr, start, x[start:start + 4])
        np.testing.assert_array_equal(arr[:], x)  # zarr-python reads tensorstore's writes
        np.testing.assert_array_equal(read_views(array_dir(arr), [9, 0, 5]), x[[9, 0, 5]])


def test_unaligned_and_nonfinite_writes_refused(tmp_path: Path) -> None:
    arr = ensure_array(_group(tmp_path), latent_array(GRID, 3, "float32"), 10, 4)
    with pytest.raises(ValueError, match="not aligned"):
        write_region(arr, 2, np.zeros((4, 3, 2, 3), np.float32))
    bad = np.zeros((4, 3, 2, 3), np.float32)
    bad[1, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN or Inf"):
        write_region(arr, 0, bad)
    assert not np.any(arr[:])


def test_misaligned_stop_wrong_fit_and_changed_shape_refused(tmp_path: Path) -> None:
    group = _group(tmp_path)
    arr = ensure_array(group, latent_array(GRID, 3, "float32"), 10, 4)
    with pytest.raises(ValueError, match=r"write \[0, 3\) is not aligned to shards of 4"):
        write_region(arr, 0, np.ones((3, 3, 2, 3), np.float32))
    write_region(arr, 8, np.ones((2, 3, 2, 3), np.float32))  # the last, short shard is fine
    with pytest.raises(ValueError, match="does not fit"):
        write_region(arr, 8, np.ones((4, 3, 2, 3), np.float32))
    with pytest.raises(ValueError, match=r"exists with shape \(10, 3, 2, 3\) float32, expected "
                                         r"\(12, 3, 2, 3\) float32; remove it or use --force"):
        ensure_array(group, latent_array(GRID, 3, "float32"), 12, 4)
    assert not np.any(arr[:8]) and np.all(arr[8:] == 1)


def test_float16_overflow_of_a_float32_shard_refused(tmp_path: Path) -> None:
    arr = ensure_array(_group(tmp_path), latent_array(GRID, 3, "float16"), 10, 4)
    big = np.zeros((4, 3, 2, 3), np.float32)
    big[2, 1, 1, 2] = 1e5  # finite in float32, Inf once cast to the array's float16
    with pytest.raises(ValueError, match="NaN or Inf"):
        write_region(arr, 4, big)
    assert not np.any(arr[:])


def test_done_marks(tmp_path: Path) -> None:
    group = _group(tmp_path)
    assert not shard_done(group, "encode", 1, "k")
    mark_shard_done(group, "encode", 1, "k")
    assert shard_done(group, "encode", 1, "k") and not shard_done(group, "encode", 1, "k2")
    assert clear_marks(group, "encode") == 1 and not shard_done(group, "encode", 1, "k")


def test_view_count_mismatch_refused(tmp_path: Path) -> None:
    _group(tmp_path, n=10)
    with pytest.raises(ValueError, match="10 views"):
        _group(tmp_path, n=11)


def test_unknown_root_version_refused(tmp_path: Path) -> None:
    root = open_root(tmp_path / "cache.zarr")
    root.attrs["m3gd_format_version"] = 99
    with pytest.raises(UnknownSchemaVersion, match="99"):
        open_root(tmp_path / "cache.zarr")


def test_xarray_reads_the_store(tmp_path: Path) -> None:
    xr = pytest.importorskip("xarray")
    group = _group(tmp_path)
    arr = ensure_array(group, latent_array(GRID, 3, "float32"), 10, 4)
    x = np.arange(np.prod(arr.shape), dtype=np.float32).reshape(arr.shape)
    for start in (0, 4, 8):
        write_region(arr, start, x[start:start + 4])
    ds = xr.open_zarr(tmp_path / "cache.zarr", group="rec/front", consolidated=False,
                      zarr_format=3)
    np.testing.assert_array_equal(ds["latents_l0"].values, x)


def test_root_created_concurrently_by_another_worker_is_opened(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from zarr.errors import ContainsGroupError

    import pipeline.cache.store as store

    path = tmp_path / "cache.zarr"
    real_create = zarr.create_group

    def lose_the_race(*args: object, **kwargs: object) -> zarr.Group:
        other = real_create(*args, **kwargs)  # the other worker writes zarr.json first ...
        other.attrs["marker"] = 1
        raise ContainsGroupError("a group exists")  # ... so this worker's create fails

    monkeypatch.setattr(store.zarr, "create_group", lose_the_race)
    root = open_root(path)  # opens the other worker's root instead of failing
    assert root.attrs["marker"] == 1 and dict(root.attrs).items() >= root_attrs().items()


def test_array_created_concurrently_by_another_worker_is_opened_and_checked(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from zarr.errors import ContainsArrayError

    group = _group(tmp_path)
    spec = latent_array(GRID, 3, "float32")
    real_create = zarr.Group.create_array

    def lose_the_race(self: zarr.Group, *args: object, **kwargs: object) -> zarr.Array:
        real_create(self, *args, **kwargs)  # the other worker's array, written first
        raise ContainsArrayError("an array exists")

    monkeypatch.setattr(zarr.Group, "create_array", lose_the_race)
    arr = ensure_array(group, spec, 10, 4)
    assert arr.shape == (10, 3, 2, 3) and arr.shards == (4, 3, 2, 3)
