"""The checksum-free copy of cache arrays (format 2's layout) holds the same values."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import zarr

from bench.support.no_checksums import strip_checksums, strip_group
from store.cache_io import read_clip
from store.shard_layout import ArrayMeta
from store.shard_reader import ShardReader
from tests.store.test_shard_reader import _store, _views


def test_stripped_arrays_read_the_same_without_crc(tmp_path: Path) -> None:
    group = _store(tmp_path / "a", _views(2), [0, 1, 2])
    names = ["latents_l0", "g", "h_cells"]
    strip_group(group, tmp_path / "b" / "rec" / "front", names)
    stripped = tmp_path / "b" / "rec" / "front"
    frames = [0, 4, 9, 10]
    want = read_clip(group, ["latents_l0", "g", "h_rows"], frames, ShardReader())
    got = read_clip(stripped, ["latents_l0", "g", "h_rows"], frames, ShardReader())
    for key, value in want.items():
        np.testing.assert_array_equal(got[key], value)
    for name in names:
        meta = ArrayMeta.parse(json.loads((stripped / name / "zarr.json").read_text()))
        assert meta is not None and not meta.crc, name
        np.testing.assert_array_equal(zarr.open_array(str(stripped / name), mode="r")[:],
                                      zarr.open_array(str(group / name), mode="r")[:])
    size = sum(p.stat().st_size for p in (stripped / "latents_l0").rglob("c/**/*")
               if p.is_file())
    assert size == 11 * 5 * 8 * 16 * 2 + 3 * (4 * 16 + 4)  # data back to back + 3 indexes


def test_an_array_without_checksums_is_refused(tmp_path: Path) -> None:
    group = _store(tmp_path / "a", _views(2), [0])
    strip_checksums(group / "latents_l0", tmp_path / "b")
    with pytest.raises(ValueError, match="not a sharded array with chunk checksums"):
        strip_checksums(tmp_path / "b", tmp_path / "c")
