"""Inspection of a mission in GrandTour's Hugging Face layout (`data/` Zarr store, `images/`).

Each topic group is a "topic": its kind (camera, lidar, odometry, tf, other) by its arrays and
attributes, its rows and their `timestamp` (float64 s, read whole: 8 bytes a row) for rates
and gaps. The `tf` attribute gives the static edges (each entry child -> its base_frame_id);
the layout has no dynamic TF. A LiDAR group has no per-point time. Opened through ingest's
`HfStore` (checked chunks, Zarr v2 or v3).
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from pipeline.ingest.sources.hf.store import DATA_DIR, HfStore
from pipeline.inspect.cameras import changes, magic
from pipeline.inspect.clouds import decide_convention, sweep_period
from pipeline.inspect.decide import decide_rig
from pipeline.inspect.model import (
    Calibration,
    CameraReport,
    CloudReport,
    Convention,
    Inspection,
    PointField,
    SweepTime,
    TfEdge,
    TopicStats,
)
from pipeline.inspect.rates import timing
from pipeline.inspect.tf import shape
from schemas.errors import DataError

SWEEPS_SAMPLED = 5
IMAGES_SAMPLED = 3


def kind(arrays: set[str], attrs: dict[str, Any], has_images: bool) -> str:
    """camera, lidar, odometry, tf or other, from a group's arrays and attributes."""
    if "camera_info" in attrs or has_images:
        return "camera"
    if "points" in arrays:
        return "lidar"
    if "pose_pos" in arrays:
        return "odometry"
    if "tf" in attrs:
        return "tf"
    return "other"


def inspect_hf(path: Path, began: float) -> Inspection:
    """The inspection of an HF mission folder."""
    store = HfStore.open(path)
    topics, clouds, cameras, odometry, edges, notes = [], [], [], [], [], []
    for group in store.groups:
        attrs = store.attrs(group)
        g = store.root[group]
        arrays = set(getattr(g, "array_keys", lambda: [])())
        k = kind(arrays, attrs, (path / "images" / group).is_dir())
        stamps = None
        if "timestamp" in arrays:
            stamps, ok = store.stamps(group)
            if not ok.all():
                notes.append(f"{store.where(group, 'timestamp')}: {int((~ok).sum())} row(s) "
                             "unreadable or not finite")  # fmt: skip
            stamps = stamps[ok]
        t = timing(stamps if stamps is not None else [])
        topics.append(TopicStats(group, f"hf {k} ({attrs.get('topic', 'no topic attribute')})",
                                 0 if stamps is None else int(stamps.size), t.first_ns,
                                 t.last_ns, t.rate_hz, t.period_s, t.n_gaps, t.gaps,
                                 (store.where(group),)))  # fmt: skip
        if k == "tf":
            edges += _tf_edges(attrs["tf"], store.where(group))
        elif k == "lidar" and stamps is not None:
            clouds.append(_cloud(store, group, attrs, stamps))
        elif k == "camera":
            cameras.append(_camera(store, group, attrs, stamps))
        elif k == "odometry":
            odometry.append((group, str(attrs.get("frame_id", "")), ""))
    notes.append("tf entries are listed child -> base_frame_id as stored; ingest reads them "
                 "by ingest.hf.tf_direction (default child_from_parent)")
    size = sum(f.stat().st_size for f in (path / DATA_DIR).rglob("*") if f.is_file())
    tf = shape(edges, {})
    decisions = decide_rig(tf, odometry, {t.topic: t.msgtype for t in topics}, clouds, cameras,
                           {t.topic: t.count for t in topics},
                           {t.topic: t.rate_hz for t in topics})  # fmt: skip
    return Inspection(str(path), f"hf-zarr (Zarr v{store.version})", {DATA_DIR: size},
                      tuple(topics), tf, tuple(clouds), tuple(cameras),
                      tuple(odometry), tuple(notes), time.perf_counter() - began,
                      decisions=decisions)  # fmt: skip


def _tf_edges(tf: Any, where: str) -> list[TfEdge]:
    """The static edges of a `tf` attribute (base_frame_id -> entry key)."""
    if not isinstance(tf, dict):
        return []
    return [TfEdge(str(e.get("base_frame_id", "?")).lstrip("/"), str(child).lstrip("/"), True,
                   where, 1) for child, e in sorted(tf.items()) if isinstance(e, dict)]


def _cloud(store: HfStore, group: str, attrs: dict[str, Any], stamps: np.ndarray) -> CloudReport:
    """A LiDAR group: its arrays as fields, point counts of its first rows (`valid`)."""
    fields = []
    for name in sorted(store.root[group].array_keys()):  # type: ignore[union-attr]
        a = store.array(group, name)
        fields.append(PointField(name, 0, a.dtype.str, 0, int(np.prod(a.shape[1:] or (1,)))))
    n = min(SWEEPS_SAMPLED, int(stamps.size))
    error = None
    try:
        valid = np.asarray(store.array(group, "valid")[:n]).reshape(n, -1)[:, 0]
    except (DataError, RuntimeError, ValueError, OSError) as err:
        valid, error = np.zeros(n, np.int64), str(err)
    sweeps = tuple(SweepTime(int(s), int(s), int(v), None, None, 0, int(s), int(s), 0)
                   for s, v in zip(stamps[:n].tolist(), valid.tolist(), strict=True))
    report = CloudReport(group, str(attrs.get("frame_id", "")), tuple(fields), 0, 0, 0, 0, False,
                         False, None, None, sweeps, sweep_period(sweeps), (),
                         Convention("", None, None), error)  # fmt: skip
    return replace(report, convention=decide_convention(report))


def _camera(store: HfStore, group: str, attrs: dict[str, Any],
            stamps: np.ndarray | None) -> CameraReport:  # fmt: skip
    """A camera group: the first image files and the `camera_info` attribute."""
    sizes, kinds = [], []
    for row in range(IMAGES_SAMPLED):
        path = store.image_path(group, row)
        if not path.is_file():
            break
        data = path.read_bytes()
        kinds.append(magic(data[:8]))
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        if img is not None and (int(img.shape[1]), int(img.shape[0])) not in sizes:
            sizes.append((int(img.shape[1]), int(img.shape[0])))
    info = attrs.get("camera_info")
    cals: tuple[Calibration, ...] = ()
    error = None
    if isinstance(info, dict):
        try:
            k = [float(v) for v in info["K"]]
            stamp = int(stamps[0]) if stamps is not None and stamps.size else 0
            cals = (Calibration(stamp, str(info.get("distortion_model", "")),
                                len(info.get("D", [])), int(info["width"]), int(info["height"]),
                                k[0], k[4], k[2], k[5]),)  # fmt: skip
        except (KeyError, TypeError, ValueError, IndexError) as err:
            error = f"{store.where(group)}: unusable camera_info attribute: {err}"
    encoding = f"{', '.join(dict.fromkeys(kinds)) or 'no'} files in images/{group}/"
    return CameraReport(group, "hf image files", f"{store.where(group)} camera_info attribute"
                        if isinstance(info, dict) else None, str(attrs.get("frame_id", "")),
                        encoding, tuple(sizes), cals, changes(cals), error)  # fmt: skip
