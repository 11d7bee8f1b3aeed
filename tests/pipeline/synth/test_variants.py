"""Sensor variants: each writes what its driver writes, and ingest keeps every message of it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.pointcloud import cloud_array, decode_cloud
from pipeline.synth.api import SynthResult, synthesize
from pipeline.synth.lidar import LidarModel, beam_dirs
from pipeline.synth.rig import PINHOLE_D, FisheyeCamera
from pipeline.synth.variants import LAYOUTS, SENSORS, VARIANTS, LidarSpec, layout_dtype
from schemas.config import IngestConfig, SynthConfig
from schemas.errors import DataError
from tests.pipeline.synth.helpers import read_topic

LIDAR = "/boxi/hesai/points_undistorted"
TINY = {"seconds": 1.0, "image_width": 96, "image_height": 64, "points_per_sweep": 1024,
        "cameras": ["front"], "depth_maps": False}  # fmt: skip
INGEST = IngestConfig.model_validate({"cameras": ["front"], "out_height": 56, "out_width": 84,
                                      "checks": {"trust_checksums": False}})  # fmt: skip
"""The checks judge every message (the synthetic chunks' checksums would let them skip)."""


def _synth(tmp: Path, variant: str, **kw: object) -> SynthResult:
    return synthesize(tmp, SynthConfig(**{**TINY, **kw, "variant": variant}), "corridor",
                      variant)  # fmt: skip


def test_the_cli_and_the_generator_know_the_same_variants_and_synth_refuses_others(
        tmp_path: Path) -> None:
    from cli.stages import VARIANT_HELP
    from schemas.time_conventions import CONVENTIONS

    assert all(n in VARIANT_HELP for n in VARIANTS)
    # the point-time group is the declared table, one variant per convention
    assert {f"time_{c.name}" for c in CONVENTIONS} <= set(VARIANTS)
    with pytest.raises(DataError, match=r"unknown synth\.variant 'nope'"):
        _synth(tmp_path, "nope")


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_layouts_keep_the_drivers_point_step(layout: str) -> None:
    fields, step = LAYOUTS[layout]
    dtype = layout_dtype(layout)
    assert dtype.itemsize == step
    assert [dtype.fields[n][1] for n, _, _ in fields] == [o for _, o, _ in fields]


COMMON = ("vlp16", "no_ring", "livox", "missing_x_nan", "missing_inf", "dense_with_nan",
          "time_u32_ns", "merged", "frames")
"""Variants whose ingest runs in the default suite; the others are marked slow."""


@pytest.mark.parametrize("variant", [v if v in COMMON else pytest.param(v, marks=pytest.mark.slow)
                                     for v in SENSORS if v != "default"])  # fmt: skip
def test_every_variant_is_ingested_without_a_reject(tmp_path: Path, variant: str) -> None:
    """Fast: 1 s, one camera, 1024 points a sweep. The end-to-end runs (select, packets,
    accuracy) are `m3gd bench variants` and the slow bench test."""
    res = _synth(tmp_path, variant)
    out = ingest_recording(res.mission_dir, tmp_path / "out", INGEST)
    assert out.rejects == {}, (variant, out.rejects)
    assert out.sweeps == res.sweeps and out.images["front"] == res.images["front"]
    assert out.odometry == res.odometry and out.unaccounted == {}


def test_point_times_of_every_convention_decode_to_the_firing_times(tmp_path: Path) -> None:
    stamps = {}
    for variant in ("default", "vlp16", "time_u32_ns"):
        res = _synth(tmp_path / variant, variant, seconds=0.3)
        (bag,) = res.mission_dir.glob("*_hesai_undist.bag")
        _, msg = read_topic(bag, LIDAR)[1]
        head = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        sweep = decode_cloud(msg, head, VARIANTS[variant].lidar.time_convention)
        stamps[variant] = (head, int(sweep.t_ns.min()), int(sweep.t_ns.max()))
        # the header stamp is the first point's time (float64 epoch seconds: to ~0.2 us)
        assert abs(int(sweep.t_ns.min()) - head) < 1_000
    # the same columns: the same last firing time (uint32 ns exact, float64 s to ~0.2 us)
    assert abs(stamps["time_u32_ns"][2] - stamps["default"][2]) < 1_000, stamps
    # 16 beams: twice the columns, the last one later in the same 0.1 s rotation (float32 s)
    assert stamps["default"][2] < stamps["vlp16"][2] < stamps["vlp16"][0] + 100_000_000


def test_vlp16_rings_are_ranks_of_elevation_and_firing_order_is_not(tmp_path: Path) -> None:
    for variant, by_elevation in (("vlp16", True), ("rings_firing_order", False)):
        res = _synth(tmp_path / variant, variant, seconds=0.2)
        (bag,) = res.mission_dir.glob("*_hesai_undist.bag")
        arr = cloud_array(read_topic(bag, LIDAR)[0][1])
        el = np.degrees(np.arctan2(arr["z"], np.hypot(arr["x"], arr["y"])))
        med = [np.median(el[arr["ring"] == r]) for r in range(16)]
        assert (np.all(np.diff(med) > 0)) == by_elevation, med


@pytest.mark.parametrize(("variant", "kind"), [("missing_nan", "nan"), ("missing_x_nan", "nan"),
                                               ("missing_inf", "posinf"),
                                               ("missing_zero", "zero")])  # fmt: skip
def test_organized_clouds_keep_every_beam(tmp_path: Path, variant: str, kind: str) -> None:
    res = _synth(tmp_path, variant, seconds=0.2)
    (bag,) = res.mission_dir.glob("*_hesai_undist.bag")
    msg = read_topic(bag, LIDAR)[0][1]
    assert msg.width == LidarModel.for_points(1024, 0, 0, 1).cols * 32
    counts = decode_cloud(msg, 0).counts
    assert getattr(counts, kind) > 0 and counts.corrupt == 0


def test_livox_scans_never_repeat_and_look_forward() -> None:
    spec = VARIANTS["livox"].lidar
    a, b = beam_dirs(spec, 64, 0), beam_dirs(spec, 64, 1)
    assert a.shape == (64, 32, 3) and not np.allclose(a, b)
    assert np.allclose(np.linalg.norm(a, axis=-1), 1.0)
    assert (a[..., 1] < -np.cos(np.deg2rad(35.5))).all()  # within 35 deg of -y (forward)


def test_a_merged_cloud_holds_both_sensors(tmp_path: Path) -> None:
    one = _synth(tmp_path / "a", "default", seconds=0.2)
    two = _synth(tmp_path / "b", "merged", seconds=0.2)
    n = [read_topic(next(r.mission_dir.glob("*_hesai_undist.bag")), LIDAR)[0][1].width
         for r in (one, two)]
    assert 1.5 * n[0] < n[1] < 2.5 * n[0]


@pytest.mark.parametrize("model", sorted(PINHOLE_D))
def test_pinhole_rays_project_back_to_their_pixels(model: str) -> None:
    import cv2

    K = np.array([[100.0, 0, 47.5], [0, 101.0, 31.5], [0, 0, 1]])
    cam = FisheyeCamera("front", "f", 96, 64, K, PINHOLE_D[model], model)
    rays = cam.pixel_rays().reshape(-1, 3).astype(np.float64)
    px, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, cam.D)
    v, u = np.mgrid[0:64, 0:96]
    err = np.abs(px[:, 0, :] - np.stack([u.ravel(), v.ravel()], axis=1)).max()
    assert err < 1e-3


def test_a_variant_the_hugging_face_layout_cannot_carry_is_refused(tmp_path: Path) -> None:
    with pytest.raises(DataError, match=r"synth\.variant 'vlp16' is written as ROS1 bags only"):
        _synth(tmp_path, "vlp16", format="hf-zarr")


def test_default_spec_is_the_hesai_xt32() -> None:
    spec = LidarSpec()
    assert spec.beams == 32 and spec.layout == "hesai" and spec.invalid is None


def test_sensor_frames_are_taken_from_the_messages_when_the_config_names_others(
        tmp_path: Path) -> None:
    from schemas.recording_index import CALIBRATION, read_index_table, table_path

    res = _synth(tmp_path, "frames", seconds=0.5)
    out = ingest_recording(res.mission_dir, tmp_path / "out", INGEST)
    assert any("TF frame 'hesai_lidar'" in w and "using 'velodyne'" in w for w in out.warnings)
    assert any("using 'cam_front_optical_frame'" in w for w in out.warnings)
    rows = read_index_table(table_path(out.index_dir, "calibration"), CALIBRATION).to_pylist()
    frames = {r["sensor"]: r["frame_id"] for r in rows}
    assert frames["lidar"] == "velodyne" and frames["front"] == "cam_front_optical_frame"
