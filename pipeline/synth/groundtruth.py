"""Ground truth written beside the bags in `<mission>/groundtruth/` (never inside a bag).

Layout (see FORMAT.md): poses.parquet, images.parquet, sweeps.parquet, depth/<camera>.zarr,
calibration.json, scene.json, config.json, faults.json.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.parquet as pq
import zarr
from zarr.codecs import BloscCodec

from packets.poses import rot_to_quat
from pipeline.synth.rig import Rig

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
GT_DIR = "groundtruth"
FORMAT_VERSION = 1

IMAGES_SCHEMA = pa.schema(
    [
        ("camera", pa.string()),
        ("index", pa.int64()),
        ("stamp_ns", pa.int64()),
        ("header_stamp_ns", pa.int64()),
        ("bag_time_ns", pa.int64()),
        ("bag", pa.string()),
        ("topic", pa.string()),
        ("jpeg_corrupt", pa.bool_()),
        ("duplicate", pa.bool_()),
        ("out_of_order", pa.bool_()),
        ("depth_index", pa.int64()),
    ]
)
SWEEPS_SCHEMA = pa.schema(
    [
        ("index", pa.int64()),
        ("stamp_ns", pa.int64()),
        ("start_ns", pa.int64()),
        ("t_end_ns", pa.int64()),
        ("n_points", pa.int64()),
        ("n_nonfinite", pa.int64()),
        ("bag", pa.string()),
        ("topic", pa.string()),
    ]
)
POSES_SCHEMA = pa.schema(
    [
        (k, pa.int64() if k == "stamp_ns" else pa.float64())
        for k in ("stamp_ns", "px", "py", "pz", "qx", "qy", "qz", "qw")
    ]
)


def write_json(path: Path, data: Any) -> None:
    """Pretty JSON, keys in insertion order."""
    path.write_text(json.dumps(data, indent=1) + "\n")


def write_rows(path: Path, rows: list[dict[str, Any]], schema: pa.Schema) -> None:
    """A Parquet table from row dicts (empty table if no rows)."""
    cols = {f.name: [r[f.name] for r in rows] for f in schema}
    pq.write_table(pa.table(cols, schema=schema), path)


def write_poses(path: Path, stamps_ns: I64, T_odom_base: F64) -> None:
    """poses.parquet: stamp_ns int64 and T_odom_base as px..pz, qx..qw float64 (N rows)."""
    q = (
        np.stack([rot_to_quat(T[:3, :3]) for T in T_odom_base])
        if len(stamps_ns)
        else np.zeros((0, 4))
    )
    cols: dict[str, npt.NDArray[Any]] = {"stamp_ns": np.asarray(stamps_ns, np.int64)}
    for i, k in enumerate(("px", "py", "pz")):
        cols[k] = T_odom_base[:, i, 3]
    for i, k in enumerate(("qx", "qy", "qz", "qw")):
        cols[k] = q[:, i]
    pq.write_table(pa.table(cols, schema=POSES_SCHEMA), path)


def calibration_json(rig: Rig) -> dict[str, Any]:
    """Per camera K, D, size, model, frame; T_base_sensor (4x4 row-major lists) for every frame."""
    frames = sorted({c for _, c, _ in rig.edges})
    cams = {
        name: {
            "frame_id": c.frame_id,
            "model": c.model,
            "width": c.width,
            "height": c.height,
            "K": c.K.tolist(),
            "D": c.D.tolist(),
        }
        for name, c in rig.cameras.items()
    }
    sensors = {name: rig.T_base(c.frame_id).tolist() for name, c in rig.cameras.items()}
    sensors["lidar"] = rig.T_base(rig.lidar_frame).tolist()
    return {
        "base_frame": rig.base_frame,
        "lidar_frame": rig.lidar_frame,
        "cameras": cams,
        "T_base_sensor": sensors,
        "T_base_frame": {f: rig.T_base(f).tolist() for f in frames},
        "edges": [{"parent": p, "child": c, "T_parent_child": T.tolist()} for p, c, T in rig.edges],
    }


class DepthWriter:
    """Per-camera zarr arrays (N, H, W) float32, metres along optical z, 0 where no hit."""

    def __init__(self, root: Path, counts: dict[str, int], height: int, width: int) -> None:
        """Create one array per camera sized for `counts[camera]` images, chunked per image."""
        root.mkdir(parents=True, exist_ok=True)
        self._arrays = {
            cam: zarr.create_array(
                store=str(root / f"{cam}.zarr"),
                shape=(max(n, 0), height, width),
                chunks=(1, height, width),
                dtype="float32",
                fill_value=0.0,
                compressors=BloscCodec(cname="zstd", clevel=3, shuffle="shuffle"),
                overwrite=True,
            )
            for cam, n in counts.items()
        }

    def write(self, camera: str, index: int, depth: F32) -> None:
        """Store image `index` of `camera`."""
        self._arrays[camera][index] = depth


def read_poses(gt_dir: Path) -> tuple[I64, F64]:
    """(stamps (N,) int64 ns, T_odom_base (N, 4, 4) float64) from poses.parquet."""
    from packets.poses import make_T, quat_to_rot

    t = pq.read_table(gt_dir / "poses.parquet").to_pydict()
    q = np.stack([t[k] for k in ("qx", "qy", "qz", "qw")], axis=1)
    p = np.stack([t[k] for k in ("px", "py", "pz")], axis=1)
    T = np.stack([make_T(quat_to_rot(qi), pi) for qi, pi in zip(q, p, strict=True)])
    return np.asarray(t["stamp_ns"], np.int64), T


def pose_at(gt_dir_or_table: tuple[I64, F64], stamp_ns: int) -> F64:
    """T_odom_base (4, 4) at an exact stamp present in poses.parquet; KeyError naming it."""
    stamps, T = gt_dir_or_table
    i = int(np.searchsorted(stamps, stamp_ns))
    if i >= stamps.size or stamps[i] != stamp_ns:
        raise KeyError(f"stamp {stamp_ns} ns is not in poses.parquet")
    pose: F64 = T[i]
    return pose
