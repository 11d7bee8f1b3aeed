"""What an item on an s3:// output fetches and uploads (pipeline.run.remote, store_sync)."""

from __future__ import annotations

import os
from pathlib import Path

from pipeline.run.remote import reads_of
from pipeline.run.stage import ItemKey
from pipeline.run.store_sync import changed, snapshot, upload_order


def test_encode_item_fetches_only_its_own_shard_of_images() -> None:
    key = ItemKey("rec", "front", 2)
    reads = reads_of("encode", key)
    assert reads.of(key)[1:] == ["cache.zarr/rec", "index/rec", "cache_done/rec"]
    assert reads.keep(key, "cache.zarr/rec/front/images/c/2/0/0/0")
    assert reads.keep(key, "cache.zarr/rec/front/valid/c/2")
    assert not reads.keep(key, "cache.zarr/rec/front/images/c/3/0/0/0")
    assert not reads.keep(key, "cache.zarr/rec/left/images/c/2/0/0/0")
    assert not reads.keep(key, "cache.zarr/rec/front/latents_l0/c/2/0/0/0")
    assert reads.keep(key, "cache.zarr/rec/front/latents_l0/zarr.json")  # metadata: always


def test_packets_and_clips_fetch_no_bulk_chunks() -> None:
    rec, clips = ItemKey("rec", shard=1), ItemKey.cross("clips")
    assert not reads_of("packets", rec).keep(rec, "cache.zarr/rec/front/images/c/1/0/0/0")
    assert reads_of("clips", clips).keep(clips, "cache.zarr/r9/left/T_world_cam/c/0/0/0")
    assert not reads_of("clips", clips).keep(clips, "cache.zarr/r9/left/h_cells/c/0/0/0")
    norm = ItemKey.cross("latent_norm")
    assert reads_of("stats", norm).of(norm) == ["cache.zarr/zarr.json", "stats/latent_parts"]


def test_changed_files_upload_with_done_marks_last(tmp_path: Path) -> None:
    (tmp_path / "cache_done").mkdir()
    (tmp_path / "old.json").write_text("x")
    before = snapshot(tmp_path)
    (tmp_path / "cache_done" / "encode.000000.json").write_text("{}")
    (tmp_path / "z.bin").write_bytes(b"1")
    (tmp_path / ".z.bin.123.tmp").write_bytes(b"partial")  # a killed atomic write
    os.utime(tmp_path / "old.json", ns=(1, 1))  # rewritten (mtime differs)
    rels = changed(before, snapshot(tmp_path))
    assert upload_order(rels) == ["old.json", "z.bin", "cache_done/encode.000000.json"]
