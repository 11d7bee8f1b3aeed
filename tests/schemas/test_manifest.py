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
    assert sorted(p.name for p in tmp_path.iterdir()) == ["manifest.json"]  # no temporary
