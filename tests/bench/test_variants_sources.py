"""The source variants of `m3gd bench variants` (issue 48 item 2): the default recording as
loose MCAP files (profiles ros1 and ros2) and as the KITTI-360 raw layout, each read through
its inspect-written configuration."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import zarr
from mcap.reader import make_reader

from bench.variants import run_variants, select_variants, variant_groups
from bench.variants_sources import (
    CELLS_TABLE,
    SOURCE_VARIANTS,
    packets_vs_default,
    source_mission,
    written_time,
)

TINY = {"seconds": 0.6, "image_width": 128, "image_height": 96, "points_per_sweep": 1024,
        "cameras": ["front"], "scenes": ["corridor"]}  # fmt: skip


def test_the_sources_are_a_group_and_listed_by_name() -> None:
    assert variant_groups()["sources"] == ["mcap_ros1", "mcap_ros2", "kitti360"]
    assert select_variants(["sources"]) == list(SOURCE_VARIANTS)
    assert set(SOURCE_VARIANTS) <= set(select_variants(None))
    assert select_variants(["mcap_*"]) == ["mcap_ros1", "mcap_ros2"]


@pytest.mark.parametrize(("name", "profile", "encoding"), [("mcap_ros1", "ros1", "ros1"),
                                                           ("mcap_ros2", "ros2", "cdr")])
def test_mcap_variants_are_loose_files_of_their_profile(tmp_path: Path, name: str,
                                                        profile: str, encoding: str) -> None:
    mission = source_mission(tmp_path, name, TINY)
    files = sorted(p.name for p in mission.iterdir())
    assert files == sorted([*(f"{name}_{s}.mcap" for s in ("anymal_state", "hdr_front",
                                                           "hesai_undist", "tf_minimal")),
                            "groundtruth"])  # fmt: skip
    for path in mission.glob("*.mcap"):
        with path.open("rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            assert reader.get_header().profile == profile and summary is not None
            assert {c.message_encoding for c in summary.channels.values()} == {encoding}


def test_kitti360_ground_truth_names_its_cameras_and_undistorts_their_depth(
        tmp_path: Path) -> None:
    mission = source_mission(tmp_path, "kitti360", TINY)
    gt = mission / "groundtruth"
    assert set(pq.read_table(gt / "images.parquet").column("camera").to_pylist()) == {
        "image_00"}  # fmt: skip
    raw = zarr.open_array(str(tmp_path / "kitti360.bags" / "kitti360" / "groundtruth" / "depth"
                              / "front.zarr"), mode="r")  # fmt: skip
    rect = zarr.open_array(str(gt / "depth" / "image_00.zarr"), mode="r")
    assert rect.shape == raw.shape
    a, b = np.asarray(raw[0]), np.asarray(rect[0])
    assert not np.array_equal(a, b)  # undistorted, not copied
    # nearest neighbour: every rectified depth is one of the raw image's depths
    assert np.isin(b[b > 0], a[a > 0]).all() and (b > 0).mean() > 0.5
    assert written_time("kitti360", ("t", "s", "absolute")) == ("", "", "")
    assert written_time("mcap_ros2", ("t", "s", "absolute")) == ("t", "s", "absolute")


def _cells(path: Path, depths: list[float | None], frames: list[int] | None = None) -> str:
    frames = frames or [0] * len(depths)
    pq.write_table(pa.table({"camera": ["front"] * len(depths), "frame": frames,
                             "row": list(range(len(depths))), "col": [0] * len(depths),
                             "depth_m": pa.array(depths, pa.float64())}), path)  # fmt: skip
    return str(path)


def test_packets_against_the_default_over_the_same_cells(tmp_path: Path) -> None:
    rows = [{"variant": "default", CELLS_TABLE: _cells(tmp_path / "d", [1.0, None, 3.0])},
            {"variant": "mcap_ros1", CELLS_TABLE: _cells(tmp_path / "a", [1.0, None, 3.000002])},
            {"variant": "mcap_ros2", CELLS_TABLE: _cells(tmp_path / "b", [1.0, None, 3.0],
                                                         [0, 0, 1])},
            {"variant": "kitti360", CELLS_TABLE: _cells(tmp_path / "k", [9.0, 9.0, 9.0])}]
    got = packets_vs_default(rows)
    assert got["mcap_ros1"] == pytest.approx(2e-6) and got["mcap_ros2"] is None  # a lost cell
    assert set(got) == {"mcap_ros1", "mcap_ros2"}  # KITTI-360: not the bags' geometry
    assert all(CELLS_TABLE not in r for r in rows)
    assert rows[1]["packets_max_diff_vs_default_m"] == got["mcap_ros1"]


@pytest.mark.slow
def test_sources_run_through_their_inspect_written_configurations(tmp_path: Path) -> None:
    """Every source variant: inspected, its written configuration run (ingest, select,
    packets, geometry), accuracy measured. The MCAP copies hold the bags' bytes: their depth
    abs-rel equals the default's exactly; KITTI-360's rectified images and 10 Hz poses keep
    it within 5 % of it."""
    figures = run_variants(tmp_path, ["sources"], {"seconds": 2.0})
    rows = {r["variant"]: r for r in figures["rows"]}
    assert list(rows) == ["default", *SOURCE_VARIANTS] and figures["refused"] == []
    assert figures["time_convention_errors"] == 0 and figures["inspect_wrong_decisions"] == 0
    assert figures["inspect_config_runs"] == {"passed": 4, "run": 4}
    assert figures["geometry_false_fail"] == 0 and figures["silent_losses"] == 0
    ref = rows["default"]
    for name in ("mcap_ros1", "mcap_ros2"):
        assert rows[name]["depth_absrel"] == ref["depth_absrel"], name
        assert (rows[name]["cells"], rows[name]["views_kept"]) == (ref["cells"],
                                                                   ref["views_kept"])
    diff = figures["source_packets_max_diff_m"]
    assert set(diff) == {"mcap_ros1", "mcap_ros2"} and all(d <= 1e-6 for d in diff.values())
    assert rows["kitti360"]["depth_absrel"] == pytest.approx(ref["depth_absrel"], rel=0.05)
    assert rows["kitti360"]["geometry"] == {"image_00": "ok"}
