"""Writing the run manifest on a full disk: one line naming the file, the old one kept."""

from __future__ import annotations

import builtins
import os
from pathlib import Path
from typing import Any

import pytest

import schemas.atomic_io
from schemas.errors import DataError
from schemas.manifest import RunManifest, read_manifest, write_manifest


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full on this system")
def test_a_full_disk_is_one_line_and_keeps_the_old_manifest(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    old = RunManifest("old", "0.1.0", {})
    write_manifest(old, tmp_path)

    def full_disk(file: Any, mode: str = "r", *args: Any, **kw: Any) -> Any:
        """The manifest's temporary opened on /dev/full: the kernel's ENOSPC on write."""
        if str(file).endswith(".tmp") and ".manifest.json." in str(file):
            return builtins.open("/dev/full", mode, *args, **kw)
        return builtins.open(file, mode, *args, **kw)

    monkeypatch.setattr(schemas.atomic_io, "open", full_disk, raising=False)
    new = RunManifest("new", "0.1.0", {"x": "y" * 100_000})  # more than one buffer's worth
    with pytest.raises(DataError) as info:
        write_manifest(new, tmp_path)
    text = str(info.value)
    assert "\n" not in text and str(tmp_path / "manifest.json") in text
    assert "No space left on device" in text and "run the same command again" in text
    assert read_manifest(tmp_path) == old
    assert sorted(p.name for p in tmp_path.iterdir()) == [  # no temporary
        ".manifest.json.crc32c", "manifest.json"]


@pytest.mark.parametrize("damage", ["truncate", "flip", "garble"])
def test_a_damaged_manifest_is_one_line_naming_the_command_that_rebuilds_it(
        tmp_path: Path, damage: str) -> None:
    """Was: a truncated manifest.json ended `verify` and `run` in a JSONDecodeError traceback;
    a flipped bit could change a finished item silently."""
    from schemas.manifest import ManifestDamaged, set_aside

    m = RunManifest("h", "v", {})
    m.mark_done("select", "rec_a", "k" * 32)
    path = write_manifest(m, tmp_path)
    data = bytearray(path.read_bytes())
    if damage == "truncate":
        path.write_bytes(bytes(data[: len(data) // 2]))
    elif damage == "flip":
        data[data.index(b"k")] ^= 1  # still JSON: only the checksum tells
        path.write_bytes(bytes(data))
    else:  # not JSON, and no sidecar to compare with
        path.write_bytes(b"\x00" * 10)
        (tmp_path / ".manifest.json.crc32c").unlink()
    with pytest.raises(ManifestDamaged) as info:
        read_manifest(tmp_path)
    line = str(info.value)
    assert "\n" not in line and str(path) in line and f"m3gd verify {tmp_path}" in line
    aside = set_aside(tmp_path)
    assert aside.name == "manifest.json.damaged" and read_manifest(tmp_path) is None


def test_a_manifest_of_another_version_is_refused_not_set_aside(tmp_path: Path) -> None:
    """An unknown version is a refusal (a newer m3gd wrote it), not damage."""
    from schemas.atomic_io import record_checksum
    from schemas.manifest import ManifestDamaged

    path = write_manifest(RunManifest("h", "v", {}, version=99), tmp_path)
    record_checksum(path)
    with pytest.raises(DataError) as info:
        read_manifest(tmp_path)
    assert not isinstance(info.value, ManifestDamaged)
