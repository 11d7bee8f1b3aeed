"""`m3gd verify`: every stored cache chunk checked; a corrupt one named and its item forgotten."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.app import app
from schemas.manifest import RunManifest, read_manifest, write_manifest
from store.cache_store import mark_shard_done, open_root
from tests.pipeline.cache.test_verify import _flip, _shard
from tests.store.test_shard_reader import _store, _views


def test_verify_names_the_corrupt_chunk_and_forgets_its_item(tmp_path: Path) -> None:
    out = tmp_path / "out"
    group = _store(out, _views(0), [0, 1, 2])
    root = open_root(out / "cache.zarr")
    mark_shard_done(root["rec/front"], "encode", 1, "k")  # type: ignore[arg-type]
    manifest = RunManifest("h", "v", {})
    manifest.mark_done("encode", "rec/front/1", "k")
    manifest.mark_done("encode", "rec/front/0", "k")
    write_manifest(manifest, out)
    clean = CliRunner().invoke(app, ["verify", str(out)])
    assert clean.exit_code == 0 and "none corrupt" in clean.output
    _flip(_shard(group, "latents_l0", 1), 11)
    result = CliRunner().invoke(app, ["verify", str(out)])
    assert result.exit_code == 1, result.output
    text = result.output.replace("\n", "")
    assert "rec/front/latents_l0 views 4..4" in text and "CRC32C mismatch" in text
    assert "redo: encode rec/front/1" in text
    after = read_manifest(out)
    assert after is not None and set(after.stages["encode"].items) == {"rec/front/0"}
    assert not (out / ".m3gd.lock").exists()  # the lock was released


def test_a_full_disk_while_verify_writes_the_manifest_is_one_line(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Was: a traceback (OSError ENOSPC) when `m3gd verify` wrote manifest.json on a full
    disk. Now one line naming the file and what to do; the previous manifest is kept, the
    lock released, and the same command run again (space freed) completes the repair."""
    import schemas.manifest

    out = tmp_path / "out"
    group = _store(out, _views(0), [0, 1, 2])
    mark_shard_done(open_root(out / "cache.zarr")["rec/front"], "encode", 1, "k")  # type: ignore[arg-type]
    manifest = RunManifest("h", "v", {})
    manifest.mark_done("encode", "rec/front/1", "k")
    write_manifest(manifest, out)
    before = (out / "manifest.json").read_bytes()
    _flip(_shard(group, "latents_l0", 1), 11)

    def full(path: Path, text: str, checksum: bool = False) -> Path:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    with monkeypatch.context() as patch:
        patch.setattr(schemas.manifest, "write_text_atomic", full)
        result = CliRunner().invoke(app, ["verify", str(out)])
    assert result.exit_code == 1 and not isinstance(result.exception, OSError), result.output
    last = result.output.strip().splitlines()[-1]
    assert "Traceback" not in result.output
    assert last.startswith("error: verify stopped: ") and "manifest.json" in last
    assert "No space left on device" in last and "run the same command again" in last
    assert (out / "manifest.json").read_bytes() == before
    assert not (out / ".m3gd.lock").exists()
    again = CliRunner().invoke(app, ["verify", str(out)])
    assert again.exit_code == 1 and "redo: encode rec/front/1" in again.output.replace("\n", "")
    after = read_manifest(out)
    assert after is not None and not after.stages["encode"].items
