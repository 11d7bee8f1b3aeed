"""Inspecting loose MCAP files: the same topics, counts, times, TF tree and reports as the bags
they were converted from; only the source's identity (path, format, file names, sizes) differs."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from pipeline.inspect.recording import inspect_recording
from pipeline.inspect.scan import open_bags
from pipeline.synth.mcap_write import bags_to_mcap
from schemas.errors import MissingInputError
from tests.pipeline.ingest.bagkit import Mission, write_mission

IDENTITY = {"path", "format", "files", "seconds"}
"""Inspection fields that name the source, not what it holds."""


def _same_but_identity(a: object, b: object) -> None:
    da, db = dataclasses.asdict(a), dataclasses.asdict(b)  # type: ignore[call-overload]
    for key in da.keys() - IDENTITY:
        if key == "topics":
            for ta, tb in zip(da[key], db[key], strict=True):
                assert {**ta, "files": ()} == {**tb, "files": ()}
                assert [f.replace(".bag", ".mcap") for f in ta["files"]] == list(tb["files"])
        else:
            assert da[key] == db[key], key


def test_inspect_of_mcap_files_matches_the_bags(tmp_path: Path) -> None:
    bags = write_mission(tmp_path / "bag", Mission(seconds=0.5))
    mcaps = tmp_path / "mcap" / "m0"
    bags_to_mcap(sorted(bags.glob("*.bag")), mcaps)
    a, b = inspect_recording(bags), inspect_recording(mcaps)
    assert (a.format, b.format) == ("rosbag1", "mcap-ros1")
    assert set(b.files) == {p.name for p in mcaps.glob("*.mcap")}
    _same_but_identity(a, b)
    one = inspect_recording(mcaps / "m0_hdr_front.mcap")
    assert [t.topic for t in one.topics] == ["/boxi/hdr/front/camera_info",
                                             "/boxi/hdr/front/image_raw/compressed"]
    assert [t.count for t in one.topics] == [5, 5] and one.topics[0].rate_hz == 10.0
    assert len(one.cameras) == 1


def test_a_file_that_is_no_bag_is_named(tmp_path: Path) -> None:
    path = tmp_path / "x.db3"
    path.write_bytes(b"x")
    with pytest.raises(MissingInputError, match=r"x\.db3: not a ROS1 \.bag file, an \.mcap file"):
        open_bags(path)
