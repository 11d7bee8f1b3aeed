"""Chunk checksums (cache format 3): every read path refuses a damaged chunk, `verify_cache`
finds it with its array and views, and `invalidate` makes the next run redo its item."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import zarr
from hypothesis import given, settings
from hypothesis import strategies as st

from dags.graph import STAGES
from pipeline.cache.verify import done_mark, invalidate, missing_arrays, verify_cache
from pipeline.run.stage import downstream_of
from schemas.cache_layout import (
    CACHE_FORMAT_VERSION,
    GridSpec,
    GroupAttrs,
    LatentNorm,
    arrays_written_by,
    check_root_attrs,
    latent_array,
    layout_arrays,
    view_meta_arrays,
    writer_stage,
)
from schemas.manifest import RunManifest
from schemas.versioning import UnknownSchemaVersion
from store.cache_io import read_clip, read_views
from store.cache_store import drop_array, ensure_array, mark_shard_done, open_root
from store.raw_shard import chunk_stride
from store.shard_layout import CorruptChunkError
from store.shard_reader import ShardReader
from tests.store.test_shard_reader import SHARD, N, _store, _views


def _flip(path: Path, offset: int, bit: int = 0) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 1 << bit
    path.write_bytes(bytes(data))


def _shard(group: Path, array: str, shard: int) -> Path:
    folder = group / array
    ndim = len(json.loads((folder / "zarr.json").read_text())["shape"])
    return folder.joinpath("c", str(shard), *["0"] * (ndim - 1))


@pytest.fixture
def group(tmp_path: Path) -> Path:
    return _store(tmp_path, _views(0), [0, 1, 2])


def test_chunks_carry_crc32c_in_the_metadata(group: Path) -> None:
    for name in ("latents_l0", "g", "h_cells"):
        meta = json.loads((group / name / "zarr.json").read_text())
        inner = meta["codecs"][0]["configuration"]["codecs"]
        assert inner[-1] == {"name": "crc32c"}, name
    assert CACHE_FORMAT_VERSION == 3


STORED = 5 * 8 * 16 * 2 + 4
"""Bytes of one stored latents chunk of the test store (data and CRC32C)."""
VIEW_1 = chunk_stride(STORED)
"""Byte offset of view 1's latents chunk in shard 0 (chunks stored every 64 bytes)."""


@pytest.mark.parametrize(("array", "byte"), [("latents_l0", VIEW_1 + 7),
                                             ("h_cells", 3)])
def test_flipped_raw_chunk_is_refused_by_every_reader(group: Path, array: str,
                                                      byte: int) -> None:  # fmt: skip
    """Was: 200 flipped mantissa bits in a latents chunk trained on without a word."""
    _flip(_shard(group, array, 0), byte)
    reader = ShardReader()
    name = "latents_l0" if array == "latents_l0" else "h"
    view = 1 if array == "latents_l0" else int(np.flatnonzero(_views(0)["g"][:, 0].any(
        axis=(1, 2)))[0])
    with pytest.raises(CorruptChunkError, match=rf"{array}/c/0/.* view {view}: the chunk "
                                                r"at byte \d+: CRC32C mismatch"):
        read_clip(group, [name, "g"] if name == "h" else [name], [view], reader)
    with pytest.raises(ValueError, match="checksum"):
        zarr.open_array(str(group / array), mode="r")[view]
    with pytest.raises(ValueError, match="Digest mismatch"):
        read_views(group / array, [view])
    report = verify_cache(group.parent.parent)
    ((bad),) = report.corrupt
    assert (bad.group, bad.array, bad.shard, bad.views) == ("rec/front", array, 0, (view, view))
    assert not report.unchecked


def test_flipped_zstd_and_unsharded_chunks_are_found(group: Path, tmp_path: Path) -> None:
    _flip(_shard(group, "g", 1), 10)  # the first stored (compressed) chunk of shard 1
    root = zarr.open_group(str(tmp_path / "cache.zarr"), mode="r+")
    meta_spec = view_meta_arrays()[0]
    arr = ensure_array(root["rec/front"], meta_spec, N, SHARD)  # type: ignore[arg-type]
    arr[:] = np.arange(N)
    _flip(_shard(group, meta_spec.name, 2), 0)
    with pytest.raises(CorruptChunkError, match=rf"{meta_spec.name}/c/2 \(views"):
        ShardReader().read_views(group / meta_spec.name, [9])
    found = {(c.array, c.shard, c.views) for c in verify_cache(tmp_path / "cache.zarr").corrupt}
    assert found == {("g", 1, (4, 4)), (meta_spec.name, 2, (8, 10))}


def test_clean_cache_verifies_and_reads(group: Path) -> None:
    report = verify_cache(group.parent.parent)
    assert report.corrupt == [] and report.checked > 3 * 3
    data = _views(0)
    got = read_clip(group, ["latents_l0"], list(range(N)), ShardReader())["latents_l0"]
    np.testing.assert_array_equal(got, data["latents_l0"])


@settings(max_examples=40, deadline=None)
@given(view=st.integers(min_value=0, max_value=SHARD - 1),
       within=st.integers(min_value=0, max_value=STORED - 1),
       bit=st.integers(min_value=0, max_value=7))
def test_any_single_bit_flip_in_a_stored_chunk_is_found(tmp_path_factory: pytest.TempPathFactory,
                                                        view: int, within: int, bit: int) -> None:
    """CRC32C catches every single-bit error: any bit of shard 0's stored chunks (data or CRC)."""
    group = _store(tmp_path_factory.mktemp("flip"), _views(0), [0])
    _flip(_shard(group, "latents_l0", 0), view * chunk_stride(STORED) + within, bit)
    assert [c.views for c in verify_cache(group.parent.parent).corrupt] == [(view, view)]
    with pytest.raises(CorruptChunkError):
        ShardReader().read_views(group / "latents_l0", [view])


def test_a_flip_in_the_padding_between_chunks_changes_no_value(group: Path) -> None:
    """The zero padding after a chunk's CRC is in no chunk: every reader returns the clean
    values and verify finds nothing (the padding carries no data to damage)."""
    _flip(_shard(group, "latents_l0", 0), STORED + 1)
    assert chunk_stride(STORED) > STORED + 1
    assert verify_cache(group.parent.parent).corrupt == []
    np.testing.assert_array_equal(ShardReader().read_views(group / "latents_l0", [0, 1]),
                                  _views(0)["latents_l0"][:2])  # fmt: skip
    np.testing.assert_array_equal(read_views(group / "latents_l0", [0, 1]),
                                  _views(0)["latents_l0"][:2])  # fmt: skip


def test_invalidate_forgets_the_item_of_that_camera_and_shard(group: Path) -> None:
    cache = group.parent.parent
    root = open_root(cache)
    cams = {}
    for cam in ("front", "left"):
        cams[cam] = root.require_group(f"rec/{cam}")
        for shard in (0, 1):
            mark_shard_done(cams[cam], "encode", shard, "k")  # type: ignore[arg-type]
    manifest = RunManifest("h", "v", {})
    for key in ("rec/front/0", "rec/front/1", "rec/left/0", "other/front/0"):
        manifest.mark_done("encode", key, "k")
    manifest.mark_done("ingest", "rec", "k")
    _flip(_shard(group, "latents_l0", 0), 3)
    damage = [(c.group, c.array, c.shard) for c in verify_cache(cache).corrupt]
    forgotten = invalidate(cache, manifest, damage, lambda s: downstream_of(STAGES, s))
    assert forgotten == ["encode rec/front/0"]
    assert set(manifest.stages["encode"].items) == {"rec/front/1", "rec/left/0", "other/front/0"}
    assert not done_mark(cache, "rec/front", "encode", 0).exists()
    assert done_mark(cache, "rec/front", "encode", 1).exists()
    assert done_mark(cache, "rec/left", "encode", 0).exists()
    assert manifest.is_done("ingest", "rec", "k")


def test_writer_stage_of_every_array() -> None:
    assert [writer_stage(a) for a in ("images", "K", "stamp_ns", "latents_l0", "latents_l1", "g",
                                  "h_cells", "valid", "T_world_cam", "nope")] == [
        "ingest", "ingest", "ingest", "encode", "encode", "packets", "packets", "select",
        "select", None]


def test_format_2_cache_is_refused_with_why() -> None:
    """Format 2 chunks carry no checksum: refused (m3gd run adds how to rebuild)."""
    with pytest.raises(UnknownSchemaVersion, match=r"cache format version 2 is not supported by "
                       r"this m3gd \(reads version 3: its chunks carry no checksums\)"):
        check_root_attrs({"m3gd_kind": "cache", "m3gd_format_version": 2}, "out/cache.zarr")
    raw = GroupAttrs("rec", "front", 1, 224, 336, 14, 4).to_attrs()
    raw["m3gd_format_version"] = 2
    with pytest.raises(UnknownSchemaVersion, match="no checksums"):
        GroupAttrs.from_attrs(raw, "x")


def test_verify_once_checks_a_chunk_on_its_first_read(group: Path) -> None:
    reader = ShardReader(verify="once")
    np.testing.assert_array_equal(reader.read_views(group / "latents_l0", [1]),
                                  _views(0)["latents_l0"][1:2])  # fmt: skip
    _flip(_shard(group, "latents_l0", 0), VIEW_1 + 7)  # rewritten: a new identity
    with pytest.raises(CorruptChunkError):
        reader.read_views(group / "latents_l0", [1])
    assert ShardReader(verify="off").read_views(group / "latents_l0", [1]).shape == (1, 5, 8, 16)


def _deps(stage: str) -> list[str]:
    return downstream_of(STAGES, stage)


def test_every_array_has_one_writer_stage_of_the_graph() -> None:
    stages = {s.name for s in STAGES}
    for spec in layout_arrays():
        assert spec.writer_stage in stages and writer_stage(spec.name) == spec.writer_stage
    assert writer_stage("latents_l3") == "encode"
    assert writer_stage("latents_lx") is None and writer_stage("nope") is None
    assert arrays_written_by("packets", with_h=False) == ("g",)
    assert set(arrays_written_by("ingest")) == {"images", "stamp_ns", "K"}


def _full_manifest(cache: Path) -> RunManifest:
    """A manifest and done-marks of two recordings, one camera each, two shards."""
    manifest = RunManifest("h", "v", {})
    for rec in ("rec", "other"):
        manifest.mark_done("ingest", rec, "k")
        manifest.mark_done("select", rec, "k")
        manifest.mark_done("stats", rec, "k")
        for shard in (0, 1):
            manifest.mark_done("encode", f"{rec}/front/{shard}", "k")
            manifest.mark_done("packets", f"{rec}/{shard}", "k")
            for stage in ("encode", "packets"):
                path = done_mark(cache, f"{rec}/front", stage, shard)
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text("{}")
    manifest.mark_done("stats", "_latent_norm", "k")
    manifest.mark_done("clips", "_clips", "k")
    return manifest


def test_a_redo_of_ingest_forgets_every_dependant_of_that_recording(tmp_path: Path) -> None:
    cache = tmp_path / "cache.zarr"
    manifest = _full_manifest(cache)
    forgotten = invalidate(cache, manifest, [("rec/front", "images", 1)], _deps)
    assert forgotten == ["ingest rec", "select rec", "encode rec/front/0", "encode rec/front/1",
                         "packets rec/0", "packets rec/1", "stats rec", "stats _latent_norm",
                         "clips _clips"]
    assert not any(done_mark(cache, "rec/front", s, k).exists()
                   for s in ("encode", "packets") for k in (0, 1))
    assert all(done_mark(cache, "other/front", s, k).exists()
               for s in ("encode", "packets") for k in (0, 1))
    assert manifest.is_done("ingest", "other", "k") and manifest.is_done("packets", "other/1", "k")


def test_a_redo_of_one_encode_shard_leaves_packets_and_other_shards(tmp_path: Path) -> None:
    cache = tmp_path / "cache.zarr"
    manifest = _full_manifest(cache)
    forgotten = invalidate(cache, manifest, [("rec/front", "latents_l0", 1)], _deps)
    assert forgotten == ["encode rec/front/1", "stats rec", "stats _latent_norm",
                         "clips _clips"]
    assert not done_mark(cache, "rec/front", "encode", 1).exists()
    assert done_mark(cache, "rec/front", "encode", 0).exists()
    assert done_mark(cache, "rec/front", "packets", 1).exists()


def test_a_missing_array_redoes_all_of_its_writers_shards(tmp_path: Path) -> None:
    cache = tmp_path / "cache.zarr"
    manifest = _full_manifest(cache)
    forgotten = invalidate(cache, manifest, [("rec/front", "g", None)], _deps)
    assert forgotten[:2] == ["packets rec/0", "packets rec/1"]
    assert not any(done_mark(cache, "rec/front", "packets", k).exists() for k in (0, 1))
    assert done_mark(cache, "rec/front", "encode", 0).exists()


def test_missing_arrays_are_found_where_their_writer_is_marked_done(group: Path) -> None:
    cache = group.parent.parent
    root = open_root(cache)
    sub = root["rec/front"]
    sub.attrs.update(GroupAttrs("rec", "front", N, 224, 336, 14, SHARD,
                                packet_mode="full").to_attrs())
    manifest = RunManifest("h", "v", {})
    manifest.mark_done("select", "rec", "k")
    mark_shard_done(sub, "packets", 0, "k")  # type: ignore[arg-type]
    found = {(m.array, m.stage) for m in missing_arrays(cache, manifest)}
    assert found == {(s.name, "select") for s in view_meta_arrays()}  # g and h_cells exist
    del sub["h_cells"]  # type: ignore[union-attr]
    assert ("h_cells", "packets") in {(m.array, m.stage) for m in missing_arrays(cache, manifest)}


def test_latent_norm_is_checked_against_the_valid_views_of_its_groups() -> None:
    norm = LatentNorm([0.0], [1.0], 10, {"a/front": 3, "b/front": 0})
    assert norm.views == 3 and norm.to_attrs()["views"] == 3
    assert LatentNorm.from_attrs(norm.to_attrs()) == norm
    assert LatentNorm.from_attrs({"mean": [0.0], "std": [1.0], "count": 1}) is None
    assert norm.stale_against({"a/front": 3, "b/front": 0, "c/front": 9}) is None
    assert "holds 4" in (norm.stale_against({"a/front": 4, "b/front": 0}) or "")
    assert "is gone" in (norm.stale_against({"a/front": 3}) or "")


def test_ensure_array_replaces_another_shape_only_when_asked(tmp_path: Path) -> None:
    root = open_root(tmp_path / "cache.zarr")
    sub = root.require_group("rec/front")
    grid = GridSpec(28, 28)
    old = ensure_array(sub, latent_array(grid, 8, "float16"), 4, 2)
    old[:] = 1
    with pytest.raises(ValueError, match="exists with shape"):
        ensure_array(sub, latent_array(grid, 4, "float16"), 4, 2)
    new = ensure_array(sub, latent_array(grid, 4, "float16"), 4, 2, replace=True)
    assert new.shape == (4, 4, 2, 2) and not new[:].any()
    drop_array(sub, "latents_l0")
    assert "latents_l0" not in sub


def test_a_truncated_manifest_is_set_aside_with_every_done_mark(tmp_path: Path) -> None:
    """Was: a JSONDecodeError traceback from verify. Now the manifest is set aside and the
    done-marks (which only it ties to stage items) removed: the next run redoes everything."""
    from pipeline.cache.verify import verify_output
    from schemas.manifest import write_manifest

    out = tmp_path / "out"
    _store(out, _views(0), [0, 1, 2])
    cache = out / "cache.zarr"
    path = write_manifest(_full_manifest(cache), out)
    path.write_bytes(path.read_bytes()[:120])
    report, forgotten = verify_output(out, _deps)
    assert report.damaged and report.manifest is not None and forgotten == []
    assert f"{path}: cut or grown" in report.manifest and "set aside as" in report.manifest
    assert (out / "manifest.json.damaged").exists() and not path.exists()
    assert not list((out / "cache_done").glob("*/*/*.json"))


def test_a_damaged_table_is_forgotten_by_verify_with_its_dependants(tmp_path: Path) -> None:
    import pyarrow as pa

    from pipeline.cache.verify import verify_output
    from schemas.atomic_io import written_by
    from schemas.manifest import read_manifest, write_manifest
    from schemas.tables import write_table

    out = tmp_path / "out"
    _store(out, _views(0), [0, 1, 2])
    write_manifest(_full_manifest(out / "cache.zarr"), out)
    schema = pa.schema([("x", pa.int64())])
    table = out / "index" / "rec" / "selection.parquet"
    with written_by("select", "rec"):
        write_table(pa.table({"x": [1, 2, 3]}, schema=schema), schema, table)
    _flip(table, 30)
    report, forgotten = verify_output(out, _deps)
    assert [(f.path, f.stage, f.item) for f in report.files] == [(table, "select", "rec")]
    assert "select rec" in forgotten and "encode rec/front/0" in forgotten
    after = read_manifest(out)
    assert after is not None and "rec" not in after.stages["select"].items
    assert "other" in after.stages["select"].items
