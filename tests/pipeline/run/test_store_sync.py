"""Which store objects an item's push deletes when it replaces a Zarr array
(pipeline.run.store_sync.layouts, replaced, stale), without a store."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import zarr

from pipeline.run.store_sync import Seen, layouts, replaced, snapshot, stale


def _array(root: Path, name: str, shard: int, attrs: dict[str, int] | None = None) -> None:
    """A sharded int32 array `name` of 12 views under `root`, `shard` views per shard."""
    group = zarr.open_group(str(root), mode="a", zarr_format=3)
    if name in group:
        del group[name]
    arr = group.create_array(name=name, shape=(12, 4), chunks=(shard, 4),
                             shards=(shard, 4), dtype="int32", fill_value=0)
    arr[:] = np.arange(48, dtype=np.int32).reshape(12, 4) + 1
    if attrs:
        arr.attrs.update(attrs)


def _seen(folder: Path) -> Seen:
    return dict(snapshot(folder))


def test_array_recreated_with_another_shard_layout_leaves_every_old_object(tmp_path: Path) -> None:
    _array(tmp_path, "a", 4)
    _array(tmp_path, "b", 4)
    seen = _seen(tmp_path)  # the store as listed at pull: c/0..c/2 of a and of b
    before = layouts(tmp_path)
    _array(tmp_path, "a", 6)  # a recreated with 6 views per shard: writes c/0 and c/1
    after = snapshot(tmp_path)
    arrays = replaced(before, layouts(tmp_path))
    assert arrays == ["a"]
    assert stale(seen, arrays, after) == ["a/c/2/0"]  # b's objects and a's new ones stay


def test_removed_array_leaves_all_its_objects_and_only_its_own(tmp_path: Path) -> None:
    _array(tmp_path, "a", 4)
    _array(tmp_path, "ab", 4)  # a name with `a` as prefix: not below a/
    seen = _seen(tmp_path)
    before = layouts(tmp_path)
    del zarr.open_group(str(tmp_path), mode="a", zarr_format=3)["a"]
    arrays = replaced(before, layouts(tmp_path))
    assert arrays == ["a"]
    assert stale(seen, arrays, snapshot(tmp_path)) == [
        "a/c/0/0", "a/c/1/0", "a/c/2/0", "a/zarr.json"]


def test_same_layout_rewrite_or_new_attributes_replace_nothing(tmp_path: Path) -> None:
    """An item that rewrites an array's zarr.json identically, changes only its attributes,
    or writes only its own shard leaves the other shards' objects on the store."""
    _array(tmp_path, "a", 4)
    before = layouts(tmp_path)
    _array(tmp_path, "a", 4, attrs={"note": 1})
    group = zarr.open_group(str(tmp_path), mode="a", zarr_format=3)
    group["a"][0:4] = 7
    assert replaced(before, layouts(tmp_path)) == []


def test_resized_array_is_replaced(tmp_path: Path) -> None:
    _array(tmp_path, "a", 4)
    before = layouts(tmp_path)
    zarr.open_group(str(tmp_path), mode="a", zarr_format=3)["a"].resize((5, 4))
    assert replaced(before, layouts(tmp_path)) == ["a"]


def test_group_metadata_is_not_an_array(tmp_path: Path) -> None:
    zarr.open_group(str(tmp_path / "g"), mode="a", zarr_format=3)
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "zarr.json").write_text("{not json")
    assert layouts(tmp_path) == {}
