"""sensor_msgs/PointCloud2 decoding driven by `msg.fields`, vectorized with numpy.

The byte layout (offsets, datatypes, endianness, point_step, row_step) is read from the message
and turned into a numpy structured dtype with explicit offsets, so an unaligned float64 (Hesai:
point_step 26) decodes without copying per point. Points with a NaN/Inf coordinate or time, or a
coordinate beyond `MAX_COORD_M`, and all-zero points are dropped and counted. `load_sweep` finds
an indexed sweep back in its bag (seek to its log time, match its header stamp) and decodes it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from pipeline.ingest.bags import BagFile, stamp_ns
from pipeline.ingest.sweep_checks import SweepPoints
from schemas.errors import DataError, MissingDataError

POINTFIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
TIME_FIELDS = ("timestamp", "t", "time", "ts", "offset_time")
ABS_SECONDS_MIN = 1e8
"""A float time field above this many seconds is an absolute (epoch) stamp, else an offset."""
ABS_NS_MIN = 10**17
"""An integer time field above this many ns is an absolute (epoch) stamp, else an offset."""
MAX_TIME_S = 9e9
"""A float time field beyond this many seconds (year 2255; int64 ns overflow at 9.2e9) is
corrupt: its points are dropped and counted."""
MAX_COORD_M = 1e5
"""A coordinate farther than this (m) is a corrupt point, not a LiDAR return: dropped and counted
with the NaN/Inf points (finite but huge values would overflow depth statistics downstream)."""


@dataclass(frozen=True)
class PointCounts:
    """Points in the message, dropped as unusable (NaN/Inf coordinate or time, or a coordinate
    beyond MAX_COORD_M: `nonfinite`), dropped for being all zero, and kept; `missing` of the
    unusable ones are NaN rows (x, y and z all NaN: a missing return of a non-dense cloud)."""

    total: int
    nonfinite: int
    zero: int
    valid: int
    missing: int = 0


class Sweep(NamedTuple):
    """A decoded sweep: xyz (N, 3) float32 m, intensity (N,) float32, t_ns (N,) int64, counts."""

    xyz: npt.NDArray[np.float32]
    intensity: npt.NDArray[np.float32]
    t_ns: npt.NDArray[np.int64]
    counts: PointCounts


def cloud_dtype(msg: Any) -> np.dtype[Any]:
    """Structured dtype of one point from msg.fields, msg.is_bigendian and msg.point_step."""
    order = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for f in msg.fields:
        if f.datatype not in POINTFIELD_TYPES:
            raise DataError(f"field {f.name!r} has unknown PointField datatype {f.datatype}")
        code = order + POINTFIELD_TYPES[f.datatype]
        count = max(int(f.count), 1)
        names.append(f.name)
        formats.append(code if count == 1 else (code, (count,)))
        offsets.append(int(f.offset))
    spec = {"names": names, "formats": formats, "offsets": offsets, "itemsize": int(msg.point_step)}
    dtype: np.dtype[Any] = np.dtype(spec)  # type: ignore[call-overload]
    return dtype


def cloud_array(msg: Any) -> npt.NDArray[np.void]:
    """(width * height,) structured array viewing the message bytes (rows trimmed of padding)."""
    dtype = cloud_dtype(msg)
    n_row = int(msg.width) * int(msg.point_step)
    data = np.asarray(msg.data, dtype=np.uint8)
    height = int(msg.height)
    if data.size < height * int(msg.row_step) or int(msg.row_step) < n_row:
        raise DataError(
            f"PointCloud2 data has {data.size} bytes, expected {height} rows of "
            f"{msg.row_step} (width {msg.width} x point_step {msg.point_step})"
        )
    if height * n_row == 0:
        return np.zeros(0, dtype=dtype)
    if int(msg.row_step) != n_row:
        rows = data[: height * int(msg.row_step)].reshape(height, int(msg.row_step))
        data = np.ascontiguousarray(rows[:, :n_row]).ravel()
    return np.frombuffer(data[: height * n_row], dtype=dtype)


def _time_field(arr: npt.NDArray[np.void]) -> str | None:
    """The first time-like field of a cloud (TIME_FIELDS order), or None."""
    names = arr.dtype.names or ()
    return next((n for n in TIME_FIELDS if n in names), None)


def _time_ns(arr: npt.NDArray[np.void], header_ns: int) -> npt.NDArray[np.int64]:
    """Per-point int64 ns stamps from the first time-like field; header stamp if there is none."""
    name = _time_field(arr)
    if name is None or arr.size == 0:
        return np.full(arr.size, header_ns, dtype=np.int64)
    v = arr[name]
    if v.dtype.kind == "f":
        v64 = v.astype(np.float64)
        v64 = np.where(np.abs(v64) < MAX_TIME_S, v64, 0.0)  # NaN too; those points are dropped
        if np.median(v64) > ABS_SECONDS_MIN:  # absolute seconds: split to keep precision
            whole = np.floor(v64)
            frac = np.rint((v64 - whole) * 1e9)
            return (whole.astype(np.int64) * 1_000_000_000 + frac.astype(np.int64)).astype(np.int64)
        return header_ns + np.rint(v64 * 1e9).astype(np.int64)
    v_int = v.astype(np.int64)
    if int(v_int.max()) > ABS_NS_MIN:
        return v_int
    return header_ns + v_int


def _time_finite(arr: npt.NDArray[np.void]) -> npt.NDArray[np.bool_] | bool:
    """Per point: its float time field (if any) is finite and below MAX_TIME_S."""
    name = _time_field(arr)
    if name is None or arr[name].dtype.kind != "f":
        return True
    v = arr[name]
    return np.abs(v) < MAX_TIME_S  # False for NaN


def _drop_masks(x: np.ndarray, y: np.ndarray, z: np.ndarray,
                arr: npt.NDArray[np.void]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(usable, zero, keep) bool masks over the points; see PointCounts."""
    usable = np.ones(x.shape, dtype=bool)
    for c in (x, y, z):
        usable &= np.abs(c) <= MAX_COORD_M  # False for NaN too
    usable &= _time_finite(arr)
    zero = usable & (x == 0) & (y == 0) & (z == 0)
    return usable, zero, usable & ~zero


def _xyz_cloud(msg: Any) -> npt.NDArray[np.void]:
    """The structured points of a PointCloud2; ValueError when x, y or z is missing."""
    arr = cloud_array(msg)
    names = arr.dtype.names or ()
    missing = [c for c in ("x", "y", "z") if c not in names]
    if missing:
        raise DataError(f"PointCloud2 lacks field(s) {missing}; has {list(names)}")
    return arr


def decode_cloud(msg: Any, header_ns: int) -> Sweep:
    """Decode x, y, z (required), intensity and per-point time; drop NaN/Inf and zero points."""
    arr = _xyz_cloud(msg)
    names = arr.dtype.names or ()
    xyz = np.stack([arr[c].astype(np.float32) for c in ("x", "y", "z")], axis=1)
    finite, zero, keep = _drop_masks(xyz[:, 0], xyz[:, 1], xyz[:, 2], arr)
    if "intensity" in names:
        inten = arr["intensity"].astype(np.float32)
    else:
        inten = np.zeros(arr.size, dtype=np.float32)
    t_ns = _time_ns(arr, header_ns)
    missing = np.isnan(xyz).all(axis=1)
    counts = PointCounts(int(arr.size), int((~finite).sum()), int(zero.sum()), int(keep.sum()),
                         int(missing.sum()))
    inten = np.nan_to_num(inten[keep], nan=0.0, posinf=0.0, neginf=0.0)
    return Sweep(np.ascontiguousarray(xyz[keep]), inten, t_ns[keep], counts)


def find_sweep(bag: BagFile, row: Mapping[str, Any]) -> Sweep:
    """The sweep of `row` in an open bag; MissingDataError (a LookupError) naming it when absent."""
    topic, log_ns, stamp = str(row["topic"]), int(row["bag_time_ns"]), int(row["stamp_ns"])
    for msg in bag.messages([topic], start=log_ns):
        if msg.bag_time_ns > log_ns:
            break
        obj = bag.deserialize(msg)
        if stamp_ns(obj) == stamp:
            return decode_cloud(obj, stamp)
    raise MissingDataError(
        f"{bag.name}: no {topic} message with log time {log_ns} ns and stamp {stamp} ns"
    )


class CloudView(NamedTuple):
    """A PointCloud2's structured points (N,) and its (usable, zero, keep) masks (N,) bool,
    decoded once for the index summary and the plausibility checks."""

    arr: npt.NDArray[np.void]
    usable: npt.NDArray[np.bool_]
    zero: npt.NDArray[np.bool_]
    keep: npt.NDArray[np.bool_]


def cloud_view(msg: Any) -> CloudView:
    """The points of a PointCloud2 and the drop masks of `decode_cloud`."""
    arr = _xyz_cloud(msg)
    return CloudView(arr, *_drop_masks(arr["x"], arr["y"], arr["z"], arr))


def cloud_summary(msg: Any, header_ns: int) -> tuple[PointCounts, int, int]:
    """Counts and (t_first_ns, t_last_ns) of the kept points, without materializing them."""
    return view_summary(cloud_view(msg), header_ns)


def view_summary(view: CloudView, header_ns: int) -> tuple[PointCounts, int, int]:
    """Counts and (t_first_ns, t_last_ns) of the kept points of `view`.

    What the index needs from a sweep; the same drop rules as `decode_cloud`. Time span is
    (header_ns, header_ns) when no point is kept.
    """
    arr, finite, zero, keep = view
    missing = np.isnan(arr["x"]) & np.isnan(arr["y"]) & np.isnan(arr["z"])
    counts = PointCounts(int(arr.size), int(arr.size - finite.sum()), int(zero.sum()),
                         int(keep.sum()), int(missing.sum()))  # fmt: skip
    if counts.valid == 0:
        return counts, header_ns, header_ns
    t_ns = _time_ns(arr, header_ns)[keep]
    return counts, int(t_ns.min()), int(t_ns.max())


def kept_points(view: CloudView, header_ns: int) -> SweepPoints:
    """The kept points of a PointCloud2 (the drop rules of `decode_cloud`) for the plausibility
    checks: xyz float64 m, time in s from `header_ns` (None without a time field), intensity
    and ring (None when the cloud lacks them)."""
    names = view.arr.dtype.names or ()
    kept = view.arr[view.keep]
    xyz = np.stack([kept[c].astype(np.float64) for c in ("x", "y", "z")], axis=1)
    t_s = None
    if _time_field(kept) is not None:
        t_s = (_time_ns(kept, header_ns) - header_ns).astype(np.float64) / 1e9
    inten = kept["intensity"].astype(np.float64) if "intensity" in names else None
    ring = kept["ring"].astype(np.int64) if "ring" in names else None
    return SweepPoints(xyz, t_s, inten, ring)
