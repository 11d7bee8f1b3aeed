"""What an item on an s3:// output fetches and uploads (pipeline.run.remote, store_sync)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from dags.graph import STAGES
from pipeline.run.keys import ItemKey
from pipeline.run.reads import Reads
from pipeline.run.remote import run_on_store
from pipeline.run.stage import Item, ItemResult, Stage
from pipeline.run.store_sync import changed, list_files, put_bytes, rel_of, snapshot, upload_order
from schemas.config import M3GDConfig
from schemas.manifest import RunManifest
from store.object_store import filesystem, parse_url


def reads_of(stage: str, key: ItemKey) -> Reads:
    """What an item `key` of the graph's stage `stage` fetches."""
    return _stage(stage).store.for_item(key)


def _stage(name: str) -> Stage:
    return next(s for s in STAGES if s.name == name)


def test_every_stage_of_the_graph_declares_its_reads() -> None:
    from pipeline.run.reads import UNDECLARED

    assert all(s.store is not UNDECLARED for s in STAGES)
    assert reads_of("synth", ItemKey("rec")).of(ItemKey("rec")) == []


def test_encode_item_fetches_only_its_own_shard_of_images() -> None:
    key = ItemKey("rec", "front", 2)
    reads = reads_of("encode", key)
    assert reads.of(key)[2:] == ["cache.zarr/rec/front", "cache_done/rec/front"]
    assert reads.keep(key, "cache_done/rec/front/encode.000002.json")
    assert not reads.keep(key, "cache_done/rec/front/encode.000003.json")
    assert reads.keep(key, "cache.zarr/rec/front/images/c/2/0/0/0")
    assert reads.keep(key, "cache.zarr/rec/front/valid/c/2")
    assert not reads.keep(key, "cache.zarr/rec/front/images/c/3/0/0/0")
    assert not reads.keep(key, "cache.zarr/rec/left/images/c/2/0/0/0")
    assert not reads.keep(key, "cache.zarr/rec/front/latents_l0/c/2/0/0/0")
    assert reads.keep(key, "cache.zarr/rec/front/latents_l0/zarr.json")  # metadata: always


def test_packets_and_clips_fetch_no_bulk_chunks() -> None:
    rec, clips = ItemKey("rec", shard=1), ItemKey.cross("clips")
    assert not reads_of("packets", rec).keep(rec, "cache.zarr/rec/front/images/c/1/0/0/0")
    assert reads_of("packets", rec).keep(rec, "cache_done/rec/left/packets.000001.json")
    assert not reads_of("packets", rec).keep(rec, "cache_done/rec/left/packets.000000.json")
    assert reads_of("clips", clips).keep(clips, "cache.zarr/r9/left/T_world_cam/c/0/0/0")
    assert not reads_of("clips", clips).keep(clips, "cache.zarr/r9/left/h_cells/c/0/0/0")
    norm = ItemKey.cross("latent_norm")
    assert reads_of("stats", norm).of(norm) == ["cache.zarr/zarr.json", "stats/latent_parts",
                                                "cache.zarr", "cache_done"]
    # the latent normalization checks its parts against the valid flags and encode marks only
    assert reads_of("stats", norm).keep(norm, "cache.zarr/r9/left/valid/c/0")
    assert not reads_of("stats", norm).keep(norm, "cache.zarr/r9/left/latents_l0/c/0/0/0/0")


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


def _fake_select(cfg: M3GDConfig, item: Item) -> ItemResult:
    """Stands in for a stage: checks what was fetched, removes one chunk, writes a mark."""
    out = Path(cfg.output_dir)
    group = out / "cache.zarr" / "rec" / "front"
    assert (group / "valid" / "c" / "0").read_bytes() == b"old"
    # fetched files carry mtime 0: a rewrite is seen even within the clock's granularity
    assert (group / "valid" / "c" / "0").stat().st_mtime_ns == 0
    assert not (group / "images").exists()  # a bulk chunk select neither reads nor writes
    (group / "valid" / "c" / "0").unlink()  # what tensorstore does to an all-fill chunk
    (group / "valid" / "c" / "1").write_bytes(b"new")
    (out / "cache_done" / "rec").mkdir(parents=True)
    (out / "cache_done" / "rec" / "select.json").write_text("{}")
    return ItemResult(done=1)


def test_item_on_store_uploads_writes_and_deletes_removed_files(s3: str) -> None:
    url, fs = parse_url(s3), filesystem()
    put_bytes(fs, url, "cache.zarr/rec/front/valid/c/0", b"old")
    put_bytes(fs, url, "cache.zarr/rec/front/images/c/0/0/0/0", b"x" * 1000)
    cfg = M3GDConfig(output_dir=Path(s3))
    result = run_on_store(_stage("select").store, _fake_select, cfg, Item(ItemKey("rec"), "k"))
    assert result.detail["store_bytes"] == {"fetched": 3, "uploaded": 5}
    keys = {rel_of(url, f) for f in list_files(fs, url, "")}
    assert keys == {"cache.zarr/rec/front/valid/c/1", "cache.zarr/rec/front/images/c/0/0/0/0",
                    "cache_done/rec/select.json"}



@pytest.mark.parametrize(("every_s", "writes"), [(3600.0, 1 + 3), (0.0, 1 + 7)])
def test_manifest_object_is_rewritten_at_most_every_interval_and_per_stage(
        s3: str, monkeypatch: pytest.MonkeyPatch, every_s: float, writes: int) -> None:
    """Toy graph of 3 stages, 7 items: one write at the start, then one per item (interval 0)
    or only at each stage's end (a long interval); every item is recorded either way."""
    from pipeline.run.executors import LocalExecutor
    from pipeline.run.remote import StoreOutput
    from pipeline.run.runner import Runner
    from schemas.config import parse_config
    from tests.pipeline.run.toy_stages import STAGES as TOY

    puts: list[int] = []
    real = StoreOutput.write_manifest

    def counted(self: StoreOutput, manifest: RunManifest) -> None:
        puts.append(sum(len(r.items) for n, r in manifest.stages.items() if n != "_generations"))
        real(self, manifest)

    monkeypatch.setattr(StoreOutput, "write_manifest", counted)
    cfg = parse_config({"output_dir": s3, "dag": {"retries": 0, "manifest_every_s": every_s}})
    Runner(cfg, TOY, progress=False).run(LocalExecutor())
    assert len(puts) == writes and puts[-1] == 7
    again = Runner(cfg, TOY, progress=False).run(LocalExecutor())
    assert [s.skipped for s in again] == [3, 3, 1]


def test_leftovers_of_a_replaced_array_are_deleted_unless_rewritten_since(s3: str) -> None:
    """`delete_unchanged`: an object another item uploaded after this item's listing (here
    c/0, rewritten with the new layout) stays; the old layout's c/1 and c/2 go."""
    from pipeline.run.store_sync import Seen, delete_unchanged, version_of

    fs, url = filesystem(), parse_url(s3)
    for n in range(3):
        put_bytes(fs, url, f"cache.zarr/r/c/a/c/{n}/0", b"old" * 10)
    seen: Seen = {rel_of(url, i): version_of(i) for i in list_files(fs, url, "cache.zarr")}
    put_bytes(fs, url, "cache.zarr/r/c/a/c/0/0", b"new layout")
    assert delete_unchanged(fs, url, sorted(seen), seen) == 2
    left = [rel_of(url, i) for i in list_files(fs, url, "cache.zarr")]
    assert left == ["cache.zarr/r/c/a/c/0/0"]


def _upload_toy_output(tmp_path: Path, s3: str) -> list[str]:
    """The toy output of the checksum tests (tables with sidecars, a done-mark) uploaded."""
    from pipeline.run.store_sync import put_file
    from tests.pipeline.run.test_checksums import _output

    local = tmp_path / "out"
    _output(local)
    mark = local / "cache_done" / "rec_a" / "front" / "packets.000001.json"
    mark.parent.mkdir(parents=True)
    mark.write_text('{"cache_key": "k"}')
    rels = sorted(p.relative_to(local).as_posix() for p in local.rglob("*") if p.is_file())
    for rel in rels:
        put_file(filesystem(), parse_url(s3), local, rel)
    return rels


def test_uploaded_tables_are_checked_against_their_uploaded_sidecars(
        tmp_path: Path, s3: str) -> None:
    """Was: a run against an s3:// output never checked the uploaded sidecars: a flipped
    byte in an uploaded table passed and the run said up to date."""
    from pipeline.run.remote import StoreOutput
    from store.object_store import read_bytes
    from tests.pipeline.run.test_checksums import GRAPH, _manifest

    rels = _upload_toy_output(tmp_path, s3)
    store, url = StoreOutput(s3), parse_url(s3)
    manifest = _manifest()
    assert store.forget_damaged(manifest, GRAPH.__getitem__) == []
    data = bytearray(read_bytes(filesystem(), url, "index/rec_a/selection.parquet") or b"")
    data[len(data) // 2] ^= 4
    put_bytes(filesystem(), url, "index/rec_a/selection.parquet", bytes(data))
    lines = store.forget_damaged(manifest, GRAPH.__getitem__)
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"{url.url('index/rec_a/selection.parquet')}: CRC32C mismatch")
    assert "written by select rec_a" in lines[0]
    assert "rec_a" not in manifest.stages["select"].items
    assert set(manifest.stages["packets"].items) == {"rec_b/front/0"}
    assert set(manifest.stages["ingest"].items) == {"rec_a", "rec_b"}
    keys = {rel_of(url, f) for f in list_files(filesystem(), url, "")}
    assert keys == set(rels) - {"cache_done/rec_a/front/packets.000001.json"}


def test_a_run_on_the_store_forgets_what_a_damaged_upload_needs_redone(
        tmp_path: Path, s3: str) -> None:
    """The run policy checks an s3:// output's uploads under its lock, as every local run
    checks its files before planning; the manifest on the store forgets the writer."""
    from pipeline.run.remote import StoreOutput
    from pipeline.run.service import check_store_tables
    from tests.pipeline.run.test_checksums import _manifest

    _upload_toy_output(tmp_path, s3)
    store, url = StoreOutput(s3), parse_url(s3)
    store.write_manifest(_manifest())
    put_bytes(filesystem(), url, "clips.parquet", b"PAR1 cut")
    check_store_tables(M3GDConfig(output_dir=Path(s3)), STAGES)
    after = store.read_manifest()
    assert after is not None and "_clips" not in after.stages["clips"].items
    assert set(after.stages["select"].items) == {"rec_a", "rec_b"}
