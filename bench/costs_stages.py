"""Per-stage timers of the cost measurement (see `bench.costs`): each runs the real
code of one stage on synthetic GrandTour-sized input and returns seconds and bytes per item."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow as pa

from bench.cache_bench import run_cache_bench
from bench.cache_data import CacheBenchSpec
from bench.ingest_bench import GRANDTOUR_D, GRANDTOUR_K
from bench.measure import fastest
from bench.packets_bench import T_CAM_LIDAR, _sweep
from model.encoders import get_image_encoder, get_point_encoder
from packets.assemble import SweepFeatures, packet_from_support, view_support
from pipeline.ingest.calib.camera import RawCamera, build_rectifier
from pipeline.ingest.sources.pointcloud import decode_cloud
from pipeline.select.views import LidarSweeps, Odometry, _select_camera
from pipeline.synth.lidar import HESAI_DTYPE
from pipeline.synth.rosio import CLOUD_T, IMAGE_T, Msgs, ros1_typestore
from schemas.cache_layout import F16_MAX, GridSpec, image_arrays, latent_array, packet_arrays
from schemas.cache_layout import view_meta_arrays as meta_arrays
from schemas.config import SelectConfig

YAWS_DEG = (0.0, 120.0, -120.0)


def _both(key: str, wall: float, cpu: float, per: int = 1) -> dict[str, float]:
    """{key_s: cpu / per, key_wall_s: wall / per}."""
    return {f"{key}_s": cpu / per, f"{key}_wall_s": wall / per}


def textured_bgr(h: int, w: int, seed: int) -> np.ndarray:
    """(h, w, 3) uint8 BGR test image: smooth gradients, edges and mild noise (JPEG-realistic)."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    base = 110 + 60 * np.sin(u / (w / 9.0)) * np.cos(v / (h / 5.0))
    blocks = 40.0 * ((u // max(1, w // 24) + v // max(1, h // 16)) % 2)
    img = np.stack([base + blocks, base * 0.8 + 30, 200 - base * 0.5], axis=-1)
    img += rng.normal(0.0, 6.0, size=img.shape).astype(np.float32)
    out: np.ndarray = np.clip(img, 0, 255).astype(np.uint8)
    return out


def raw_camera(raw_hw: tuple[int, int]) -> RawCamera:
    """A GrandTour-like equidistant camera with K scaled from 1920x1280 to (h, w) pixels."""
    h, w = raw_hw
    K = GRANDTOUR_K.copy()
    K[0] *= w / 1920.0
    K[1] *= h / 1280.0
    return RawCamera("front", "hdr_front", w, h, "equidistant", K, GRANDTOUR_D.copy())


def output_cameras(out_hw: tuple[int, int]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Pinhole K (3, 3) of the output size (~111 deg wide) and 3 T_cam_lidar (4, 4) yawed views."""
    h, w = out_hw
    f = 115.0 * w / 336.0
    K = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    Ts = []
    for yaw in np.deg2rad(YAWS_DEG):
        rz = np.eye(4)
        rz[:2, :2] = [[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]]
        Ts.append(T_CAM_LIDAR @ rz)
    return K, Ts


def image_costs(raw_hw: tuple[int, int], out_hw: tuple[int, int], repeats: int,
                seed: int) -> tuple[dict[str, float], np.ndarray]:
    """Ingest cost per image and one rectified (out_h, out_w, 3) uint8 RGB output."""
    ts = ros1_typestore()
    ok, buf = cv2.imencode(".jpg", textured_bgr(*raw_hw, seed), [cv2.IMWRITE_JPEG_QUALITY, 90])
    if not ok:
        raise RuntimeError(f"cv2.imencode failed for a {raw_hw} image")
    jpeg = np.asarray(buf, dtype=np.uint8).ravel()
    raw = ts.serialize_ros1(Msgs(ts).image(1_000_000_000, "hdr_front", jpeg, 0), IMAGE_T)
    rect = build_rectifier(raw_camera(raw_hw), out_hw)

    def run() -> np.ndarray:
        msg = ts.deserialize_ros1(raw, IMAGE_T)
        return rect.apply(msg.data, "costs/front")

    wall, cpu, rgb = fastest(run, repeats)
    return {**_both("ingest_image", wall, cpu), "jpeg_bytes": float(jpeg.size),
            "jpeg_reduction": float(rect.reduction)}, rgb


def sweep_costs(n_points: int, repeats: int, seed: int) -> tuple[dict[str, float], np.ndarray]:
    """PointCloud2 deserialization + decoding cost per sweep, and the decoded xyz (N, 3) float32."""
    ts = ros1_typestore()
    xyz = _sweep(np.random.default_rng(seed), n_points)
    pts = np.zeros(xyz.shape[0], dtype=HESAI_DTYPE)
    for i, c in enumerate("xyz"):
        pts[c] = xyz[:, i]
    pts["intensity"] = 10.0
    pts["ring"] = np.arange(xyz.shape[0]) % 32
    pts["timestamp"] = 1.7e9 + np.arange(xyz.shape[0]) * (0.1 / xyz.shape[0])
    raw = ts.serialize_ros1(Msgs(ts).cloud(1_700_000_000_000_000_000, "hesai_lidar", pts, 0),
                            CLOUD_T)

    def run() -> np.ndarray:
        return decode_cloud(ts.deserialize_ros1(raw, CLOUD_T), 1_700_000_000_000_000_000).xyz

    wall, cpu, out = fastest(run, repeats)
    return {**_both("decode_sweep", wall, cpu), "sweep_bytes": float(pts.nbytes),
            "n_points": float(out.shape[0])}, out


def select_cost(n_views: int, repeats: int) -> dict[str, float]:
    """Seconds per view of the selection of `n_views` 10 Hz images (20 Hz odometry, 10 Hz LiDAR)."""
    sec_ns = 1_000_000_000
    t0 = 1_700_000_000 * sec_ns
    tau = t0 + sec_ns + np.arange(n_views, dtype=np.int64) * (sec_ns // 10)
    sweeps = t0 + np.arange(n_views + 40, dtype=np.int64) * (sec_ns // 10) + 3_000_000
    m = 2 * n_views + 80
    odo_t = t0 + np.arange(m, dtype=np.int64) * (sec_ns // 20)
    pos = np.column_stack([np.linspace(0.0, 0.05 * m, m), np.zeros(m), np.zeros(m)])
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (m, 1))
    rows = pa.table({"frame": pa.array(np.arange(n_views), pa.int64()),
                     "stamp_ns": pa.array(tau, pa.int64())})
    calib: dict[str, object] = {"T_base_sensor": np.eye(4).ravel().tolist(),
                                "K_out": np.eye(3).ravel().tolist()}
    odo = Odometry(odo_t, pos, quat)
    cfg = SelectConfig()
    gap = round(cfg.max_odom_gap_s * 1e9)

    def run() -> Any:
        ids = np.arange(len(sweeps), dtype=np.int64)  # one LiDAR: sweep ids are positions
        lidar = LidarSweeps("lidar", ids, sweeps, np.eye(4))
        return _select_camera("front", rows, lidar, odo, calib, cfg, gap)

    wall, cpu, (table, _) = fastest(run, repeats)
    if table.num_rows != n_views:
        raise RuntimeError(f"selection gave {table.num_rows} rows for {n_views} views")
    return _both("select_view", wall, cpu, n_views)


def encoder_costs(rgb: np.ndarray, xyz: np.ndarray, point_channels: int, da3: bool,
                  repeats: int, seed: int) -> tuple[dict[str, float], np.ndarray]:
    """Seconds per image of `patch` (and `da3`), per sweep of `fpfh` at C_u channels (one run,
    it is the slow one), and the sweep's fpfh features (N, C_u) float32."""
    out: dict[str, float] = {}
    patch = get_image_encoder("patch", channels=768, seed=seed)
    wall, cpu, _ = fastest(lambda: patch.encode(rgb[None]), repeats)
    out.update(_both("encode_patch_image", wall, cpu))
    if da3:
        net = get_image_encoder("da3", allow_random_init=True, seed=seed, levels=(0,))
        net.encode(rgb[None])  # first call allocates; not timed
        wall, cpu, _ = fastest(lambda: net.encode(rgb[None]), repeats)
        out.update(_both("encode_da3_image", wall, cpu))
    fpfh = get_point_encoder("fpfh", channels=point_channels, seed=seed)
    wall, cpu, feat = fastest(lambda: fpfh.encode(xyz), 1)
    out.update(_both("encode_fpfh_sweep", wall, cpu))
    return out, feat


def packet_cost(xyz: np.ndarray, feat: SweepFeatures, out_hw: tuple[int, int],
                repeats: int) -> dict[str, float]:
    """Seconds per view of building and casting a 'full' packet, and the occupied-cell fraction."""
    K, Ts = output_cameras(out_hw)

    def run() -> int:
        occupied = 0
        for T in Ts:
            sup = view_support(xyz, K, T, out_hw)
            pkt = packet_from_support(sup, 0.02, feat, mode="full")
            assert pkt.h is not None and pkt.g is not None
            np.clip(pkt.h, -F16_MAX, F16_MAX).astype(np.float16)
            occupied += pkt.stats.n_occupied_cells
        return occupied

    wall, cpu, occupied = fastest(run, repeats)
    grid = GridSpec(*out_hw)
    return {**_both("packet_view", wall, cpu, len(Ts)),
            "occupancy": occupied / (len(Ts) * grid.grid_h * grid.grid_w)}


def view_bytes(out_hw: tuple[int, int], channels: int, point_channels: int) -> dict[str, float]:
    """Uncompressed bytes per view of each cached array group, from `schemas.cache_layout`."""
    grid = GridSpec(*out_hw)

    def size(specs: list[Any]) -> float:
        return float(sum(np.dtype(s.dtype).itemsize * math.prod(s.view_shape) for s in specs))

    images = [s for s in image_arrays(grid) if s.name == "images"]
    meta = [s for s in image_arrays(grid) if s.name != "images"] + meta_arrays()
    return {"image_bytes_view": size(images),
            "latent_bytes_view": size([latent_array(grid, channels, "float16")]),
            "packet_raw_bytes_view": size(packet_arrays(grid, point_channels, True)),
            "meta_bytes_view": size(meta)}


def cache_costs(out_hw: tuple[int, int], channels: int, point_channels: int, occupancy: float,
                views: int, workdir: Path | None) -> dict[str, float]:
    """Zarr write throughput (uncompressed bytes/s) and packet compression, small cache bench."""
    span = max(2, min(20, views // 2))
    spec = CacheBenchSpec(views=views, channels=channels, point_channels=point_channels,
                          image_h=out_hw[0], image_w=out_hw[1], occupancy=occupancy,
                          shard_views=min(64, views), clips=8, clip_views=min(4, span),
                          clip_span=span)
    bench = run_cache_bench(spec, workdir)
    return {"cache_write_bytes_s": bench["zarr_write_mb_s"] * 1e6,
            "packet_bytes_ratio": bench["packet_bytes_ratio"]}
