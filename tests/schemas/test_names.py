"""Names under an output root (recordings, missions) and the cameras synthesized recordings have."""

from __future__ import annotations

import pytest

from schemas.config import ConfigError, parse_config
from schemas.names import check_name, name_problem


@pytest.mark.parametrize("bad", ["", ".", "..", "../x", "a/b", "/abs", "a\\b", "__meta",
                                 " pad", "tab\tname", "x" * 201, "zarr.json", "manifest.json",
                                 ".tmp", ".hidden"])
def test_names_that_leave_their_root_or_zarr_cannot_hold_are_refused(bad: str) -> None:
    assert name_problem(bad) is not None
    with pytest.raises(ValueError, match="mission name"):
        check_name(bad, "mission name")


@pytest.mark.parametrize("good", ["2024-11-03-10-04-22", "synth_corridor_s0", "m.1", "a..b"])
def test_ordinary_names_pass(good: str) -> None:
    assert check_name(good, "mission name") == good


def test_recording_folder_named_dotdot_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match=r"ingest.*folder name '\.\.'"):
        parse_config({"ingest": {"recordings": ["data/m1/.."]}})


def test_ingest_cameras_follow_synth_cameras_unless_set() -> None:
    """Was: synth.cameras [front] with the default ingest.cameras asked for left and right too,
    and recorded 4 rejects for topics never meant to exist."""
    assert parse_config({"synth": {"cameras": ["front"]}}).ingest.cameras == ["front"]
    both = {"synth": {"cameras": ["front"]}, "ingest": {"cameras": ["front", "left"]}}
    assert parse_config(both).ingest.cameras == ["front", "left"]  # set: the user's choice
    real = {"synth": {"cameras": ["front"]}, "ingest": {"recordings": ["/data/m1"]}}
    assert parse_config(real).ingest.cameras == ["front", "left", "right"]  # not synthesized


def test_a_camera_named_after_the_stores_metadata_file_is_a_config_error() -> None:
    """Was: a camera named zarr.json turned the recording group's metadata into a folder."""
    with pytest.raises(ConfigError, match=r"camera name 'zarr.json'.*file the store writes"):
        parse_config({"ingest": {"cameras": ["front", "zarr.json"]}})
