"""sensor_msgs/PointCloud2 decoding driven by `msg.fields`, vectorized with numpy.

The byte layout (offsets, datatypes, endianness, point_step, row_step) is read from the message
and turned into a numpy structured dtype with explicit offsets, so an unaligned float64 (Hesai:
point_step 26) decodes without copying per point.

The message's contract decides what a point is (PCL, REP 117): a point with NaN or +-Inf in any
coordinate is an invalid return (NaN: no measurement, +Inf: no return, -Inf: too close), and so
is an all-zero point (a convention of many drivers); they are dropped and counted by kind. A
finite coordinate beyond `MAX_COORD_M`, or a time that is NaN/Inf or beyond `MAX_TIME_S` on a
point with finite coordinates, is a value no sensor produces: `corrupt` (the sweep is damaged).
`load_sweep` finds an indexed sweep back in its bag (seek to its log time, match its header
stamp) and decodes it.
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
    """Points of one message by kind: `total`; invalid returns with a non-finite coordinate
    (`nonfinite` = `nan` + `posinf` + `neginf`: a point with a NaN coordinate counts as nan,
    else one with a +Inf as posinf, else -Inf); finite all-zero points (`zero`); `corrupt`
    points (a finite coordinate beyond MAX_COORD_M or a bad time: damage); and the `valid`
    (kept) rest."""

    total: int
    nonfinite: int
    zero: int
    valid: int
    nan: int = 0
    posinf: int = 0
    neginf: int = 0
    corrupt: int = 0

    def kinds(self) -> str:
        """The dropped points in one phrase, e.g. '12 NaN, 3 +Inf, 0 -Inf, 5 zero'."""
        return f"{self.nan} NaN, {self.posinf} +Inf, {self.neginf} -Inf, {self.zero} zero"


def sweep_counts(c: PointCounts) -> dict[str, int]:
    """The count columns of a sweeps-table row (`schemas.recording_index.SWEEPS`)."""
    return {"n_points": c.total, "n_valid": c.valid, "n_nonfinite": c.nonfinite, "n_nan": c.nan,
            "n_posinf": c.posinf, "n_neginf": c.neginf, "n_zero": c.zero}


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
        with np.errstate(invalid="ignore"):
            ok = np.abs(v64) < MAX_TIME_S  # False for NaN: those points are dropped
        v64 = np.where(ok, v64, 0.0)
        if ok.any() and np.median(v64[ok]) > ABS_SECONDS_MIN:  # absolute s: split for precision
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
    with np.errstate(invalid="ignore"):
        return np.abs(arr[name]) < MAX_TIME_S  # False for NaN


class PointKinds(NamedTuple):
    """(N,) bool masks of one cloud's points by kind (disjoint; see PointCounts)."""

    nan: npt.NDArray[np.bool_]
    posinf: npt.NDArray[np.bool_]
    neginf: npt.NDArray[np.bool_]
    corrupt: npt.NDArray[np.bool_]
    zero: npt.NDArray[np.bool_]
    keep: npt.NDArray[np.bool_]

    def counts(self) -> PointCounts:
        """The counts of each kind."""
        nan, pos, neg = int(self.nan.sum()), int(self.posinf.sum()), int(self.neginf.sum())
        return PointCounts(int(self.keep.size), nan + pos + neg, int(self.zero.sum()),
                           int(self.keep.sum()), nan, pos, neg, int(self.corrupt.sum()))


def point_kinds(x: np.ndarray, y: np.ndarray, z: np.ndarray,
                arr: npt.NDArray[np.void] | None = None) -> PointKinds:
    """Classify points (N,) by coordinates and (for `arr` with a float time field) time."""
    with np.errstate(invalid="ignore"):
        nan = np.isnan(x) | np.isnan(y) | np.isnan(z)
        pos = ~nan & ((x == np.inf) | (y == np.inf) | (z == np.inf))
        neg = ~nan & ~pos & ((x == -np.inf) | (y == -np.inf) | (z == -np.inf))
        invalid = nan | pos | neg
        far = (np.abs(x) > MAX_COORD_M) | (np.abs(y) > MAX_COORD_M) | (np.abs(z) > MAX_COORD_M)
    corrupt = ~invalid & far
    if arr is not None:
        corrupt |= ~invalid & ~np.asarray(_time_finite(arr), dtype=bool)
    zero = ~invalid & ~corrupt & (x == 0) & (y == 0) & (z == 0)
    keep = ~(invalid | corrupt | zero)
    return PointKinds(nan, pos, neg, corrupt, zero, keep)


def _xyz_cloud(msg: Any) -> npt.NDArray[np.void]:
    """The structured points of a PointCloud2; ValueError when x, y or z is missing."""
    arr = cloud_array(msg)
    names = arr.dtype.names or ()
    missing = [c for c in ("x", "y", "z") if c not in names]
    if missing:
        raise DataError(f"PointCloud2 lacks field(s) {missing}; has {list(names)}")
    return arr


def decode_cloud(msg: Any, header_ns: int) -> Sweep:
    """Decode x, y, z (required), intensity and per-point time; drop invalid, corrupt and zero
    points (`point_kinds`)."""
    arr = _xyz_cloud(msg)
    names = arr.dtype.names or ()
    xyz = np.stack([arr[c].astype(np.float32) for c in ("x", "y", "z")], axis=1)
    kinds = point_kinds(xyz[:, 0], xyz[:, 1], xyz[:, 2], arr)
    keep = kinds.keep
    if "intensity" in names:
        inten = arr["intensity"].astype(np.float32)
    else:
        inten = np.zeros(arr.size, dtype=np.float32)
    t_ns = _time_ns(arr, header_ns)
    counts = kinds.counts()
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
    """A PointCloud2's structured points (N,) and their kinds, decoded once for the index
    summary and the plausibility checks."""

    arr: npt.NDArray[np.void]
    kinds: PointKinds

    @property
    def keep(self) -> npt.NDArray[np.bool_]:
        """(N,) bool: the kept points."""
        return self.kinds.keep


def cloud_view(msg: Any) -> CloudView:
    """The points of a PointCloud2 and the drop masks of `decode_cloud`."""
    arr = _xyz_cloud(msg)
    return CloudView(arr, point_kinds(arr["x"], arr["y"], arr["z"], arr))


def cloud_summary(msg: Any, header_ns: int) -> tuple[PointCounts, int, int]:
    """Counts and (t_first_ns, t_last_ns) of the kept points, without materializing them."""
    return view_summary(cloud_view(msg), header_ns)


def view_summary(view: CloudView, header_ns: int) -> tuple[PointCounts, int, int]:
    """Counts and (t_first_ns, t_last_ns) of the kept points of `view`.

    What the index needs from a sweep; the same drop rules as `decode_cloud`. Time span is
    (header_ns, header_ns) when no point is kept.
    """
    arr, keep = view.arr, view.keep
    counts = view.kinds.counts()
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
