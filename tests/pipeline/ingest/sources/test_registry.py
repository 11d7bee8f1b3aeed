"""The source registry: which source reads a location, the same on a local folder and on S3,
and what a folder no source claims says."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.ingest.sources.base import list_names
from pipeline.ingest.sources.registry import SOURCES, resolve, source_for, source_named
from pipeline.ingest.sources.staging import mission_identity, remote_entries
from pipeline.stages.common import input_identity
from schemas.errors import DataError
from tests.s3_fixture import upload


def _hf_layout(root: Path) -> Path:
    """The file names of a small Hugging Face mission (contents are not read here)."""
    for name, data in [("data/.zgroup", b"{}"), ("data/lidar/.zarray", b"{}"),
                       ("data/lidar/.zattrs", b"{}"), ("data/lidar/0.0", b"x" * 40),
                       ("images/cam0/000000.jpeg", b"j" * 10),
                       ("images/cam0/000001.jpeg", b"j" * 12)]:
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_bytes(data)
    return root


def _bags(root: Path) -> Path:
    root.mkdir(parents=True)
    for name in ("b_10.bag", "b_2.bag", "a.mcap"):
        (root / name).write_bytes(b"x" * 5)
    (root / "notes.txt").write_text("x")
    return root


def test_every_row_has_a_distinct_name() -> None:
    names = [s.name for s in SOURCES]
    assert len(set(names)) == len(names) and {"rosbag", "hf-zarr"} <= set(names)
    with pytest.raises(DataError, match=r"unknown input format 'nope'; one of .*rosbag"):
        source_named("nope")


def test_detection_by_listing(tmp_path: Path) -> None:
    hf = _hf_layout(tmp_path / "hf")
    bags = _bags(tmp_path / "bags")
    (tmp_path / "empty").mkdir()
    assert source_for(hf).name == "hf-zarr"
    assert source_for(bags).name == "rosbag"
    assert source_for(bags / "a.mcap").name == "rosbag"
    assert source_for(tmp_path / "empty").name == "rosbag"  # the fallback names what it skipped
    assert "data/lidar/.zarray" not in list_names(hf, 2)  # detection stays shallow


def test_a_configured_format_the_folder_lacks(tmp_path: Path) -> None:
    bags = _bags(tmp_path / "bags")
    with pytest.raises(DataError, match=r"ingest\.format is hf-zarr but there is no Zarr store"):
        resolve(bags, "hf-zarr")
    src, detected = resolve(_hf_layout(tmp_path / "hf"), "auto")
    assert (src.name, detected) == ("hf-zarr", True)


def test_local_identity_names(tmp_path: Path) -> None:
    hf = _hf_layout(tmp_path / "hf")
    got = [Path(i["path"]).relative_to(hf.resolve()).as_posix() for i in input_identity(hf)]
    assert got == ["data/lidar/.zarray", "data/lidar/.zattrs", "images/cam0"]
    bags = _bags(tmp_path / "bags")
    got = [Path(i["path"]).name for i in input_identity(bags)]
    assert got == ["b_10.bag", "b_2.bag", "a.mcap"]  # bags, then MCAP files, by name


def test_remote_folders_sum_their_objects() -> None:
    entries = remote_entries([("images/c/1.jpeg", 10, 5), ("images/c/2.jpeg", 12, 7)])
    assert entries["images/c/"] == (22, 7) and entries["images/"] == (22, 7)


def test_an_hf_mission_on_s3_has_the_local_identity(s3: str, tmp_path: Path) -> None:
    hf = _hf_layout(tmp_path / "m9")
    upload(hf, f"{s3}/m9")
    ident = mission_identity(Path(f"{s3}/m9"))
    assert [i["path"].removeprefix(f"{s3}/m9/") for i in ident] == [
        "data/lidar/.zarray", "data/lidar/.zattrs", "images/cam0"]
    assert ident[-1]["size"] == 22  # the image folder: its objects' bytes
