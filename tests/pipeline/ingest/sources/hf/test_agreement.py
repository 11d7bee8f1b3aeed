"""Agreement is the test: one synthetic recording, ingested from bags and from the HF layout.

Same selection (sweep per image, Delta-tau within 1 us), same packets g (float tolerance),
byte-identical cached images; the faulty recording gives the same rejects. What must differ
(no per-point time, locations, stamps rounded through float64 seconds) is checked as such.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zarr

from dags.graph import STAGES
from pipeline.ingest.recording import ingest_recording
from pipeline.run.service import RunRequest, run_stages
from schemas.config import M3GDConfig, parse_config
from schemas.recording_index import INDEX_TABLES, SELECTION, read_index_table, table_path
from tests.pipeline.ingest.sources.hf.kit import INGEST, mission

FORMATS = ("rosbag", "hf-zarr")
STAMP_TOL_NS = 120  # float64 seconds near 1.7e9 s resolve 0.24 us: rounding is within half


def _cfg(out: Path, rec: Path) -> M3GDConfig:
    return parse_config({
        "output_dir": str(out),
        "ingest": {"recordings": [str(rec)], "out_height": 112, "out_width": 168},
        "packets": {"mode": "geom_only"}, "encoders": {"point_channels": 16},
        "cache": {"shard_views": 16}, "dag": {"retries": 0},
    })  # fmt: skip


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Output folder of ingest + select + packets per format (the 'clean' recording)."""
    outs = {}
    for fmt in FORMATS:
        out = tmp_path_factory.mktemp(f"agree_{fmt}")
        cfg = _cfg(out, mission(tmp_path_factory, "clean", fmt))
        only = RunRequest(only=("ingest", "select", "packets"))
        summaries = run_stages(cfg, STAGES, only).summaries
        assert not any(s.failed for s in summaries), [s.failed for s in summaries]
        outs[fmt] = out
    return outs


def _table(out: Path, name: str) -> list[dict[str, Any]]:
    schema = SELECTION if name == "selection" else INDEX_TABLES[name]
    rows: list[dict[str, Any]] = read_index_table(
        table_path(out / "index" / "clean", name), schema).to_pylist()
    return rows


def test_same_selection(runs: dict[str, Path]) -> None:
    bag, hf = (_table(runs[f], "selection") for f in FORMATS)
    assert len(bag) == len(hf) > 50
    assert sum(r["status"] == "ok" for r in bag) > 30
    for a, b in zip(bag, hf, strict=True):
        assert (a["camera"], a["frame"], a["sweep"], a["status"], a["reason"]) == (
            b["camera"], b["frame"], b["sweep"], b["status"], b["reason"])
        assert abs(a["dtau_s"] - b["dtau_s"]) < 1e-6
        assert abs(a["stamp_ns"] - b["stamp_ns"]) <= STAMP_TOL_NS
        # odometry interpolated at stamps up to 0.12 us apart (robot moving ~1 m/s, ~1 rad/s)
        np.testing.assert_allclose(a["T_cam_lidar"], b["T_cam_lidar"], atol=1e-6)
        np.testing.assert_allclose(a["T_world_cam"], b["T_world_cam"], atol=1e-6)
        assert a["K_out"] == b["K_out"]


def test_same_packets_and_byte_identical_images(runs: dict[str, Path]) -> None:
    caches = [zarr.open_group(str(runs[f] / "cache.zarr"), mode="r") for f in FORMATS]
    for cam in ("front", "left", "right"):
        a, b = (c[f"clean/{cam}"] for c in caches)
        img_a, img_b = a["images"][:], b["images"][:]
        assert img_a.shape == img_b.shape and img_a.tobytes() == img_b.tobytes()
        g_a, g_b = a["g"][:], b["g"][:]
        assert (g_a[:, 0] == 1).sum() > 100  # views with LiDAR support
        np.testing.assert_array_equal(g_a[:, 0], g_b[:, 0])  # same occupied cells
        np.testing.assert_allclose(g_a, g_b, rtol=1e-5, atol=1e-6)


def test_index_differs_only_where_it_must(runs: dict[str, Path]) -> None:
    for name in ("sweeps", "odometry", "images", "calibration"):
        bag, hf = (_table(runs[f], name) for f in FORMATS)
        assert len(bag) == len(hf) > 0, name
    bag_sw, hf_sw = (_table(runs[f], "sweeps") for f in FORMATS)
    for a, b in zip(bag_sw, hf_sw, strict=True):
        assert abs(a["stamp_ns"] - b["stamp_ns"]) <= STAMP_TOL_NS
        assert [a[k] for k in ("n_points", "n_valid", "n_nonfinite", "n_zero")] == [
            b[k] for k in ("n_points", "n_valid", "n_nonfinite", "n_zero")]
        assert a["t_last_ns"] - a["t_first_ns"] > 50_000_000  # per-point time in the bag
        assert b["t_first_ns"] == b["t_last_ns"] == b["stamp_ns"]  # none in the release
        assert b["file"] == "data/hesai_points_undistorted" and b["ordinal"] == b["sweep"]
    hf_img = _table(runs["hf-zarr"], "images")
    assert hf_img[0]["file"] == "images/hdr_front/000000.jpeg"
    bag_od, hf_od = (_table(runs[f], "odometry") for f in FORMATS)
    for a, b in zip(bag_od, hf_od, strict=True):
        assert a["position"] == b["position"] and a["quat_xyzw"] == b["quat_xyzw"]


def test_faulty_recording_gives_the_same_rejects(tmp_path_factory: pytest.TempPathFactory,
                                                 tmp_path: Path) -> None:
    res = {f: ingest_recording(mission(tmp_path_factory, "faulty", f), tmp_path / f, INGEST)
           for f in FORMATS}  # fmt: skip
    assert res["rosbag"].rejects == res["hf-zarr"].rejects
    assert set(res["rosbag"].rejects) >= {"corrupt_jpeg", "duplicate_stamp", "out_of_order_stamp",
                                          "empty_sweep", "stream_gap",
                                          "missing_camera_info"}  # fmt: skip
    # the nan_points sweeps hold invalid returns (NaN, +Inf in x): kept, counted by kind
    assert "nonfinite_points" not in res["rosbag"].rejects
    kinds = [(read_index_table(table_path(res[f].index_dir, "sweeps"), INDEX_TABLES["sweeps"])
              .select(["n_nan", "n_posinf", "n_neginf"]).to_pylist()) for f in FORMATS]
    assert kinds[0] == kinds[1] and sum(r["n_posinf"] > 0 for r in kinds[0]) == 2
    assert res["rosbag"].images == res["hf-zarr"].images
    for name in ("images", "sweeps", "odometry"):
        a, b = (read_index_table(table_path(res[f].index_dir, name), INDEX_TABLES[name])
                .column("stamp_ns").to_numpy() for f in FORMATS)  # fmt: skip
        assert a.shape == b.shape and np.abs(a - b).max() <= STAMP_TOL_NS, name


def test_input_format_is_reported(runs: dict[str, Path], tmp_path_factory: pytest.TempPathFactory,
                                  tmp_path: Path) -> None:
    rec = mission(tmp_path_factory, "clean", "hf-zarr")
    assert ingest_recording(rec, tmp_path, INGEST).input_format == "hf-zarr (Zarr v2), detected"
    cfg = INGEST.model_copy(update={"format": "hf-zarr"})
    assert ingest_recording(rec, tmp_path, cfg).input_format.endswith("set by ingest.format")
    bags = mission(tmp_path_factory, "clean", "rosbag")
    assert ingest_recording(bags, tmp_path, INGEST).input_format == "rosbag, detected"
    with pytest.raises(ValueError, match=r"ingest\.format is hf-zarr but there is no Zarr store"):
        ingest_recording(bags, tmp_path, cfg)
