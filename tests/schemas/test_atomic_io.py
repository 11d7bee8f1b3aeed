"""Atomic writes: errors name the file."""

from __future__ import annotations

import errno
from pathlib import Path
from typing import BinaryIO

import pytest

from schemas.atomic_io import write_atomic


def test_a_full_disk_names_the_file(tmp_path: Path) -> None:
    """Was: `[Errno 28] No space left on device` with no path; the temporary is removed."""
    def full(f: BinaryIO) -> None:
        f.write(b"x")
        raise OSError(errno.ENOSPC, "No space left on device")

    target = tmp_path / "a" / "shard"
    with pytest.raises(OSError, match=rf"No space left on device: '{target}'") as info:
        write_atomic(target, full)
    assert info.value.errno == errno.ENOSPC and not list(target.parent.iterdir())


def test_a_checksummed_write_records_size_crc_and_writer(tmp_path: Path) -> None:
    """The sidecar names the stage item running the write, and matches the bytes."""
    import google_crc32c

    from schemas.atomic_io import Checksum, check_file, checksum_path, write_text_atomic, written_by

    target = tmp_path / "t" / "table.json"
    with written_by("select", "rec_a"):
        write_text_atomic(target, '{"a": 1}', checksum=True)
    sidecar = checksum_path(target)
    assert sidecar.name == ".table.json.crc32c"
    found = Checksum.from_json(sidecar.read_text(), str(sidecar))
    crc = format(google_crc32c.value(b'{"a": 1}'), "08x")
    assert found == Checksum("table.json", 8, crc, "select", "rec_a")
    assert check_file(target) is None
    write_text_atomic(tmp_path / "plain.json", "{}")  # no checksum asked: no sidecar
    assert not checksum_path(tmp_path / "plain.json").exists()


@pytest.mark.parametrize(("damage", "why"), [
    ("flip", "CRC32C mismatch"), ("cut", "cut or grown: 3 bytes, 8 written"),
    ("delete", "missing"), ("sidecar", "its checksum sidecar cannot be read")])
def test_every_damage_of_a_checksummed_file_is_named(tmp_path: Path, damage: str,
                                                     why: str) -> None:
    """A flipped bit, a cut, a deleted file and a garbled sidecar each give a reason."""
    from schemas.atomic_io import check_file, checksum_path, write_text_atomic

    target = write_text_atomic(tmp_path / "m.json", '{"a": 1}', checksum=True)
    data = bytearray(target.read_bytes())
    if damage == "flip":
        data[5] ^= 4
        target.write_bytes(bytes(data))
    elif damage == "cut":
        target.write_bytes(bytes(data[:3]))
    elif damage == "delete":
        target.unlink()
    else:
        checksum_path(target).write_text('{"kind": "m3gd-checksum", "vers')
    reason = check_file(target)
    assert reason is not None and reason.startswith(why), reason


def test_a_file_without_sidecar_is_not_judged(tmp_path: Path) -> None:
    from schemas.atomic_io import check_file

    (tmp_path / "old.parquet").write_bytes(b"PAR1")
    assert check_file(tmp_path / "old.parquet") is None


def test_a_table_amended_by_a_later_stage_keeps_its_creator(tmp_path: Path) -> None:
    """checks.parquet is written by ingest and amended by a later stage: a damaged one is
    redone by ingest (which rewrites it whole), not by the stage that reads it to amend."""
    from schemas.atomic_io import checksum_path, read_sidecar, write_text_atomic, written_by

    target = tmp_path / "checks.json"
    with written_by("ingest", "rec"):
        write_text_atomic(target, "[1]", checksum=True)
    with written_by("geometry", "rec"):
        write_text_atomic(target, "[1, 2]", checksum=True)
    found = read_sidecar(checksum_path(target))
    assert found is not None and (found.stage, found.item, found.size) == ("ingest", "rec", 6)
    with written_by("ingest", "rec"):  # the creator's rerun stays the writer
        write_text_atomic(target, "[1]", checksum=True)
    found = read_sidecar(checksum_path(target))
    assert found is not None and found.stage == "ingest"
