"""Checksum sidecars of an output's tables: the damaged ones named with their writer, and
what the next run must redo forgotten."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pytest

from pipeline.run.checksums import forget_files, guarded_files, verify_files, writer_of
from schemas.atomic_io import checksum_path, write_text_atomic, written_by
from schemas.manifest import RunManifest
from schemas.tables import write_table

GRAPH = {"ingest": ["ingest", "select", "packets", "stats", "clips"],
         "select": ["select", "packets", "stats", "clips"],
         "packets": ["packets", "stats", "clips"], "stats": ["stats", "clips"],
         "clips": ["clips"]}
SCHEMA = pa.schema([("x", pa.int64())])


def _output(out: Path) -> dict[str, Path]:
    """A toy output: a table per writer, as the stages lay them out."""
    files = {}
    for stage, item, rel in [("ingest", "rec_a", "index/rec_a/images.parquet"),
                             ("select", "rec_a", "index/rec_a/selection.parquet"),
                             ("ingest", "rec_b", "index/rec_b/images.parquet"),
                             ("packets", "rec_a/front/1", "stats/parts/rec_a/view-1.parquet"),
                             ("stats", "rec_a", "stats/view_stats/rec_a.parquet"),
                             ("clips", "_clips", "clips.parquet")]:
        with written_by(stage, item):
            write_table(pa.table({"x": list(range(50))}, schema=SCHEMA), SCHEMA, out / rel)
        files[rel] = out / rel
    write_text_atomic(out / "notes.json", "{}", checksum=True)  # written outside a stage
    return files


def _manifest() -> RunManifest:
    m = RunManifest("h", "v", {})
    for stage, items in {"ingest": ["rec_a", "rec_b"], "select": ["rec_a", "rec_b"],
                         "packets": ["rec_a/front/0", "rec_a/front/1", "rec_b/front/0"],
                         "stats": ["rec_a", "rec_b", "_latent_norm"],
                         "clips": ["_clips"]}.items():
        for item in items:
            m.mark_done(stage, item, "k")
    return m


def test_a_clean_output_has_nothing_damaged(tmp_path: Path) -> None:
    files = _output(tmp_path)
    assert len(guarded_files(tmp_path)) == len(files) + 1
    assert verify_files(tmp_path) == (len(files) + 1, [])


@pytest.mark.parametrize("damage", ["flip", "cut", "delete"])
def test_a_damaged_table_is_named_with_its_writer(tmp_path: Path, damage: str) -> None:
    """Was: a flipped bit in selection.parquet left a readable table with a changed row,
    and verify found nothing."""
    path = _output(tmp_path)["index/rec_a/selection.parquet"]
    data = bytearray(path.read_bytes())
    if damage == "flip":
        data[len(data) // 3] ^= 16
        path.write_bytes(bytes(data))
    elif damage == "cut":
        path.write_bytes(bytes(data[:-9]))
    else:
        path.unlink()
    checked, damaged = verify_files(tmp_path)
    assert checked == 7 and [(d.path, d.stage, d.item) for d in damaged] == [
        (path, "select", "rec_a")]
    assert str(path) in damaged[0].line() and "select rec_a" in damaged[0].line()


def test_forgetting_a_shard_table_redoes_its_shard_and_what_reads_it(tmp_path: Path) -> None:
    path = _output(tmp_path)["stats/parts/rec_a/view-1.parquet"]
    path.write_bytes(path.read_bytes()[:-1] + b"x")
    manifest = _manifest()
    forgotten = forget_files(tmp_path / "cache.zarr", manifest, verify_files(tmp_path)[1],
                             GRAPH.__getitem__)
    assert forgotten == ["packets rec_a/front/1", "stats rec_a", "stats _latent_norm",
                         "clips _clips"]
    assert set(manifest.stages["packets"].items) == {"rec_a/front/0", "rec_b/front/0"}
    assert set(manifest.stages["ingest"].items) == {"rec_a", "rec_b"}


def test_forgetting_a_cross_item_keeps_the_recordings(tmp_path: Path) -> None:
    path = _output(tmp_path)["clips.parquet"]
    path.unlink()
    manifest = _manifest()
    forgotten = forget_files(tmp_path / "cache.zarr", manifest, verify_files(tmp_path)[1],
                             GRAPH.__getitem__)
    assert forgotten == ["clips _clips"]
    assert set(manifest.stages["stats"].items) == {"rec_a", "rec_b", "_latent_norm"}


def test_a_file_written_outside_a_stage_is_named_but_redoes_nothing(tmp_path: Path) -> None:
    _output(tmp_path)
    (tmp_path / "notes.json").write_text("{ }")
    manifest = _manifest()
    damaged = verify_files(tmp_path)[1]
    assert [d.stage for d in damaged] == [None] and "rerun the command" in damaged[0].line()
    assert forget_files(tmp_path / "cache.zarr", manifest, damaged, GRAPH.__getitem__) == []


def test_an_index_table_with_a_garbled_sidecar_is_owned_by_its_path(tmp_path: Path) -> None:
    path = _output(tmp_path)["index/rec_b/images.parquet"]
    checksum_path(path).write_text("garbage")
    assert writer_of(tmp_path, path) == ("ingest", "rec_b")
    damaged = verify_files(tmp_path)[1]
    assert [(d.path, d.stage) for d in damaged] == [(path, "ingest")]


def _tiny_cache(out: Path) -> Path:
    """A cache with one camera group of 5 views holding an array of every writer stage."""
    from schemas.cache_layout import (
        GridSpec,
        GroupAttrs,
        image_arrays,
        latent_array,
        packet_arrays,
        view_meta_arrays,
    )
    from store.cache_store import ensure_array, ensure_group, open_root

    grid = GridSpec(28, 42)
    group = ensure_group(open_root(out / "cache.zarr"),
                         GroupAttrs("rec", "front", 5, 28, 42, 14, 2))
    for spec in [*image_arrays(grid), *view_meta_arrays(), latent_array(grid, 8, "float16"),
                 *packet_arrays(grid, 4, True)]:
        ensure_array(group, spec, 5, 2)
    return out / "cache.zarr" / "rec" / "front"


def test_the_cache_metadata_as_written_passes_and_every_parsing_flip_is_named(
        tmp_path: Path) -> None:
    """Array and recording-group metadata carry no sidecar (Zarr writes them): a flipped bit
    that still parses is told apart from what the layout declares all the same."""
    from pipeline.run.checksums import cache_metadata, metadata_problem

    group = _tiny_cache(tmp_path)
    files = cache_metadata(tmp_path)
    assert len(files) == 3 + 11 and all(metadata_problem(p) is None for p in files)
    parsed = 0
    for meta in (group / "g" / "zarr.json", group / "valid" / "zarr.json",
                 group.parent / "zarr.json"):
        data = meta.read_bytes()
        for at in range(0, len(data), 3):
            for bit in (0, 5):
                meta.write_bytes(data[:at] + bytes([data[at] ^ 1 << bit]) + data[at + 1:])
                try:
                    json.loads(meta.read_bytes())
                    parsed += 1
                except ValueError:
                    pass
                assert metadata_problem(meta) is not None, (meta, at, bit)
        meta.write_bytes(data)
    assert parsed > 50  # flips a parse check alone lets through


def test_damaged_cache_metadata_is_named_with_its_writer(tmp_path: Path) -> None:
    import zarr

    from pipeline.run.checksums import damaged_metadata

    group = _tiny_cache(tmp_path)
    zarr.open_array(str(group / "valid"), mode="r+")[:] = True  # chunks: a node without meta
    (group / "latents_l0" / "zarr.json").write_text("{")
    (group / "valid" / "zarr.json").unlink()
    (group.parent / "zarr.json").write_text('{"zarr_format": 3}')
    found = {str(f.path.relative_to(tmp_path)): (f.stage, f.item, f.camera, f.detail)
             for f in damaged_metadata(tmp_path, [])}
    assert found["cache.zarr/rec/front/latents_l0/zarr.json"][:3] == ("encode", "rec", "front")
    assert found["cache.zarr/rec/front/valid/zarr.json"] == ("select", "rec", None, "missing")
    assert found["cache.zarr/rec/zarr.json"][:3] == ("ingest", "rec", None)
    assert len(found) == 3
