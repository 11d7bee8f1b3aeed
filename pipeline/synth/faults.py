"""Fault injection: a plan decided before writing (so generation can stream) and a log of what
was actually injected (faults.json).

Targets (a camera that is not configured falls back to the first configured camera):
- corrupt_jpeg: two `front` images (frames b and b + 3, b = n // 4) whose JPEG bytes lose the SOI
  marker and 40 % of their tail (cv2.imdecode returns None).
- duplicate_stamps: `front` frame b + 5 written twice with the same header stamp (bag time +1 us).
- out_of_order_stamps: `front` frames b + 7 and b + 8 exchange header stamps (bag times stay in
  capture order, so header stamps go backwards once).
- camera_gap: `left` publishes nothing for min(3 s, 30 % of the recording) in the middle.
- lidar_gap: no sweep starts within min(1 s, 25 % of the recording) in the last third.
- nan_points: two sweeps get 5 % of their points set to NaN and 1 % to +-Inf.
- empty_sweep: one sweep is published with zero points.
- missing_camera_info: `right` publishes no CameraInfo at all.
- missing_tf_edge: /tf_static lacks the edge hdr_base -> hdr_right (with missing_camera_info also
  on, both hit `right`; inject them in separate missions to observe each on its own).
- truncated_bag: the `hesai_undist` bag is cut to 75 % of its bytes after writing (the ROS2
  copy, if any, is converted before the cut and stays whole).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from pipeline.synth.timeline import NS, Timeline
from schemas.errors import DataError

FAULT_KINDS = (
    "truncated_bag", "corrupt_jpeg", "nan_points", "empty_sweep", "missing_camera_info",
    "missing_tf_edge", "duplicate_stamps", "out_of_order_stamps", "camera_gap", "lidar_gap",
)  # fmt: skip
TRUNCATE_FRACTION = 0.75


def _pick(cameras: list[str], preferred: str) -> str:
    return preferred if preferred in cameras else cameras[0]


@dataclass
class FaultPlan:
    """What to break, keyed by (camera, frame index) or sweep index; `log` collects records."""

    corrupt: set[tuple[str, int]] = field(default_factory=set)
    duplicate: set[tuple[str, int]] = field(default_factory=set)
    swap: set[tuple[str, int]] = field(default_factory=set)  # i swaps header stamps with i + 1
    camera_gap: dict[str, tuple[int, int]] = field(default_factory=dict)  # [start, end) ns
    lidar_gap: tuple[int, int] | None = None
    nan_sweeps: set[int] = field(default_factory=set)
    empty_sweeps: set[int] = field(default_factory=set)
    no_camera_info: set[str] = field(default_factory=set)
    drop_edge: tuple[str, str] | None = None
    truncate: str | None = None  # bag suffix
    log: list[dict[str, Any]] = field(default_factory=list)

    def in_camera_gap(self, camera: str, stamp_ns: int) -> bool:
        """Whether an image of `camera` at `stamp_ns` falls in its planned gap."""
        g = self.camera_gap.get(camera)
        return g is not None and g[0] <= stamp_ns < g[1]

    def in_lidar_gap(self, start_ns: int) -> bool:
        """Whether a sweep starting at `start_ns` falls in the planned LiDAR gap."""
        return self.lidar_gap is not None and self.lidar_gap[0] <= start_ns < self.lidar_gap[1]

    def record(self, kind: str, bag: str, topic: str, **detail: Any) -> None:
        """Append one injected fault to the log."""
        self.log.append({"kind": kind, "bag": bag, "topic": topic, **detail})


def plan_faults(kinds: list[str], tl: Timeline, cameras: list[str]) -> FaultPlan:
    """A deterministic plan for the requested fault kinds (ValueError on an unknown kind)."""
    unknown = sorted(set(kinds) - set(FAULT_KINDS))
    if unknown:
        raise DataError(f"unknown fault kind(s) {unknown}; known: {list(FAULT_KINDS)}")
    plan = FaultPlan()
    front, left, right = (_pick(cameras, c) for c in ("front", "left", "right"))
    n_img = tl.camera_ns[front].size
    n_sw = tl.sweep_start_ns.size
    seconds = n_sw * tl.sweep_period_ns / NS  # nominal length
    base = min(n_img // 4, max(0, n_img - 10))  # distinct front frames for the message faults
    if "corrupt_jpeg" in kinds:
        plan.corrupt |= {(front, base), (front, min(n_img - 1, base + 3))}
    if "duplicate_stamps" in kinds:
        plan.duplicate.add((front, min(n_img - 1, base + 5)))
    if "out_of_order_stamps" in kinds and n_img >= 2:
        plan.swap.add((front, min(n_img - 2, base + 7)))
    if "camera_gap" in kinds:
        gap = round(min(3.0, 0.3 * seconds) * NS)
        mid = tl.t0_ns + (tl.end_ns - tl.t0_ns) // 2
        plan.camera_gap[left] = (mid - gap // 2, mid - gap // 2 + gap)
    if "lidar_gap" in kinds:
        gap = round(min(1.0, 0.25 * seconds) * NS)
        start = tl.t0_ns + (tl.end_ns - tl.t0_ns) * 2 // 3
        plan.lidar_gap = (start, start + gap)
    if "nan_points" in kinds:
        plan.nan_sweeps |= {n_sw // 5, n_sw // 5 + 2} if n_sw > 3 else {0}
    if "empty_sweep" in kinds:
        plan.empty_sweeps.add(min(n_sw - 1, n_sw // 5 + 1))
    if "missing_camera_info" in kinds:
        plan.no_camera_info.add(right)
    if "missing_tf_edge" in kinds:
        plan.drop_edge = ("hdr_base", f"hdr_{right}")
    if "truncated_bag" in kinds:
        plan.truncate = "hesai_undist"
    return plan


def corrupt_jpeg(jpeg: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """JPEG bytes without their SOI marker and 40 % of the tail (undecodable)."""
    out = jpeg[: max(4, int(jpeg.size * 0.6))].copy()
    out[:2] = 0
    return out


def poison_points(points: npt.NDArray[np.void], rng: np.random.Generator) -> int:
    """Set 5 % of the points' x, y, z to NaN and 1 % to +-Inf in place; returns how many."""
    n = points.size
    idx = rng.permutation(n)
    n_nan, n_inf = max(1, n // 20), max(1, n // 100)
    for k in ("x", "y", "z"):
        points[k][idx[:n_nan]] = np.nan
    points["x"][idx[n_nan : n_nan + n_inf]] = np.inf
    points["y"][idx[n_nan : n_nan + n_inf]] = -np.inf
    return int(min(n, n_nan + n_inf))


def truncate_file(path: Path, fraction: float = TRUNCATE_FRACTION) -> tuple[int, int]:
    """Cut a file to `fraction` of its bytes; returns (bytes before, bytes after)."""
    data = path.read_bytes()
    keep = int(len(data) * fraction)
    path.write_bytes(data[:keep])
    return len(data), keep
