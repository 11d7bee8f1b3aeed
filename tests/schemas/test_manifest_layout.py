"""Run manifest and cache layout contracts."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from schemas.cache_layout import (
    CACHE_FORMAT_VERSION,
    CELL_BLOCK,
    EncoderIdentity,
    GridSpec,
    GroupAttrs,
    cell_block,
    latent_array,
    region_for,
    shard_regions,
)
from schemas.manifest import InputIdentity, RunManifest, read_manifest, write_manifest
from schemas.versioning import UnknownSchemaVersion


def test_manifest_round_trip(tmp_path: Path) -> None:
    bag = tmp_path / "a.bag"
    bag.write_bytes(b"x" * 10)
    man = RunManifest("abc", "0.1.0", {"zarr": "3.1.6"}, [InputIdentity.of(bag)])
    man.mark_done("ingest", "rec0", "key1")
    write_manifest(man, tmp_path)
    back = read_manifest(tmp_path)
    assert back == man
    assert back is not None and back.is_done("ingest", "rec0", "key1")
    assert not back.is_done("ingest", "rec0", "key2")
    assert back.inputs[0].size == 10


def test_manifest_unknown_version(tmp_path: Path) -> None:
    raw = json.loads(RunManifest("a", "b", {}).to_json())
    raw["version"] = 7
    (tmp_path / "manifest.json").write_text(json.dumps(raw))
    with pytest.raises(UnknownSchemaVersion, match=r"manifest\.json"):
        read_manifest(tmp_path)


def test_group_attrs_round_trip() -> None:
    enc = EncoderIdentity("patch", "1", "seed0", False, 768)
    attrs = GroupAttrs("rec", "front", 10, 224, 336, 14, 4, image_encoder=enc)
    back = GroupAttrs.from_attrs(json.loads(json.dumps(attrs.to_attrs())), "x")
    assert back == attrs


@pytest.mark.parametrize("version", [1, CACHE_FORMAT_VERSION + 1])  # 1: dense h, before packing
def test_group_attrs_unknown_version(version: int) -> None:
    raw = GroupAttrs("rec", "front", 1, 224, 336, 14, 4).to_attrs()
    raw["m3gd_format_version"] = version
    with pytest.raises(UnknownSchemaVersion, match=f"cache group format version {version} is"):
        GroupAttrs.from_attrs(raw, "store/rec/front")


def test_shard_regions_cover_views_once() -> None:
    regions = shard_regions(130, 64)
    assert regions == [(0, 64), (64, 128), (128, 130)]
    assert region_for(2, 130, 64) == (128, 130)
    with pytest.raises(IndexError):
        region_for(3, 130, 64)


def test_latent_spec_shapes() -> None:
    spec = latent_array(GridSpec(224, 336), 1536, "float16")
    assert spec.shape(5) == (5, 1536, 16, 24)
    assert spec.chunks(64) == (1, 1536, 16, 24)
    assert spec.shards(64) == (64, 1536, 16, 24)


def test_cell_block_divides_the_grid_and_is_as_large_as_allowed() -> None:
    assert cell_block(16 * 24) == CELL_BLOCK == 64
    assert cell_block(8 * 12) == 48  # 96 cells: 64 does not divide
    assert cell_block(7 * 11) == 11 and cell_block(5) == 5 and cell_block(1) == 1
    for n in range(1, 300):
        assert n % cell_block(n) == 0 and cell_block(n) <= CELL_BLOCK
