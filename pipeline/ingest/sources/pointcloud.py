"""sensor_msgs/PointCloud2 decoding driven by `msg.fields`, vectorized with numpy.

The byte layout (offsets, datatypes, endianness, point_step, row_step) is read from the message
and turned into a numpy structured dtype with explicit offsets, so an unaligned float64 (Hesai:
point_step 26) decodes without copying per point.

The message's contract decides what a point is (PCL, REP 117): a point with NaN or +-Inf in any
coordinate is an invalid return (NaN: no measurement, +Inf: no return, -Inf: too close), and so
is an all-zero point (a convention of many drivers); they are dropped and counted by kind. A
finite coordinate beyond `MAX_COORD_M` is a value no sensor produces: `corrupt` (the sweep is
damaged). Per-point time follows the topic's convention (`schemas.time_conventions`, decided
once per topic by ingest); a time value never makes a point corrupt: one that cannot be read
(NaN, Inf, beyond int64 ns) takes the header stamp, and without a convention every point does.
`find_sweep` finds an indexed sweep back in its bag (seek to its log time, match its header
stamp) and decodes it with the convention its index row names.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from pipeline.ingest.checks.sweep_checks import SweepPoints
from pipeline.ingest.sources.bags import BagFile, stamp_ns
from schemas.errors import DataError, MissingDataError
from schemas.time_conventions import TIME_FIELDS, SweepTimes, TimeConvention, to_ns

POINTFIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8", 9: "i8",
                    10: "u8"}  # fmt: skip
"""PointField datatypes (INT64 9 and UINT64 10: PCL, ros2/common_interfaces#301)."""
MAX_COORD_M = 1e5
"""A coordinate farther than this (m) is a corrupt point, not a LiDAR return: dropped and counted
with the NaN/Inf points (finite but huge values would overflow depth statistics downstream)."""


@dataclass(frozen=True)
class PointCounts:
    """Points of one message by kind: `total`; invalid returns with a non-finite coordinate
    (`nonfinite` = `nan` + `posinf` + `neginf`: a point with a NaN coordinate counts as nan,
    else one with a +Inf as posinf, else -Inf); finite all-zero points (`zero`); `corrupt`
    points (a finite coordinate beyond MAX_COORD_M: damage); and the `valid`
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


READ_FIELDS = ("x", "y", "z", "intensity", "ring", *TIME_FIELDS)
"""The fields the reader takes values from: their bytes must be their own."""


class FieldSpan(NamedTuple):
    """One declared PointField: name, datatype code, byte offset, element count (`count`)."""

    name: str
    datatype: int
    offset: int
    elements: int

    @property
    def end(self) -> int:
        """One past the field's last byte within a point (count 0 reads as 1, as PCL does)."""
        size = np.dtype(POINTFIELD_TYPES[self.datatype]).itemsize
        return self.offset + size * max(self.elements, 1)


def layout_problem(fields: Sequence[FieldSpan], point_step: int) -> str | None:
    """Why a PointCloud2 layout contradicts its own contract (one phrase), or None.

    The message says each field's bytes lie within one point (`offset + size * count <=
    point_step`) and a field name means one thing. A field the reader uses (READ_FIELDS)
    must not share bytes with another field (a `y` declared at `x`'s offset would read x
    twice); overlaps between fields the reader never reads are not its business (unsupported
    is not damaged). Pure: no I/O.
    """
    names = [f.name for f in fields]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        return f"field name(s) {dup} declared more than once"
    for f in fields:
        if f.datatype not in POINTFIELD_TYPES:
            return f"field {f.name!r} has unknown PointField datatype {f.datatype}"
        if f.end > point_step:
            return (f"field {f.name!r} (offset {f.offset}, {max(f.elements, 1)} x "
                    f"{POINTFIELD_TYPES[f.datatype]}) ends at byte {f.end}, past point_step "
                    f"{point_step}")
    for i, a in enumerate(fields):
        for b in fields[i + 1:]:
            if a.offset < b.end and b.offset < a.end and (a.name in READ_FIELDS
                                                          or b.name in READ_FIELDS):
                return (f"fields {a.name!r} (bytes {a.offset}..{a.end - 1}) and {b.name!r} "
                        f"(bytes {b.offset}..{b.end - 1}) overlap")
    return None


def field_spans(msg: Any) -> tuple[FieldSpan, ...]:
    """The declared PointFields of a PointCloud2 message."""
    return tuple(FieldSpan(str(f.name), int(f.datatype), int(f.offset), int(f.count))
                 for f in msg.fields)  # fmt: skip


def cloud_dtype(msg: Any) -> np.dtype[Any]:
    """Structured dtype of one point from msg.fields, msg.is_bigendian and msg.point_step;
    DataError naming the contradiction when the layout breaks its contract (`layout_problem`)."""
    problem = layout_problem(field_spans(msg), int(msg.point_step))
    if problem is not None:
        raise DataError(f"PointCloud2 layout: {problem}")
    order = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for f in msg.fields:
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


def time_field(arr: npt.NDArray[np.void]) -> str | None:
    """The first time-like field of a cloud (`TIME_FIELDS` order), or None."""
    return time_field_named(arr.dtype.names or ())


def time_field_named(names: Sequence[str]) -> str | None:
    """The per-point time field the reader uses among field `names`: the first of
    `TIME_FIELDS` present, or None (`m3gd inspect` reports the same one)."""
    return next((n for n in TIME_FIELDS if n in names), None)


def _time_ns(arr: npt.NDArray[np.void], header_ns: int,
             conv: TimeConvention | None) -> npt.NDArray[np.int64]:  # fmt: skip
    """Per-point int64 ns stamps under `conv`; the header stamp without a convention (or when
    the cloud lacks its field)."""
    if conv is None or conv.field not in (arr.dtype.names or ()) or arr.size == 0:
        return np.full(arr.size, header_ns, dtype=np.int64)
    return to_ns(arr[conv.field], header_ns, conv)[0]


def sweep_times(view: CloudView, header_ns: int, field: str | None) -> SweepTimes:
    """The evidence of one cloud for `auto` (`schemas.time_conventions.infer`): its header
    stamp, the finite values of `field` on kept points, the least finite value of any point."""
    if field is None or field not in (view.arr.dtype.names or ()) or view.arr.size == 0:
        return SweepTimes(header_ns, np.zeros(0), np.nan)
    v = view.arr[field].astype(np.float64)
    with np.errstate(invalid="ignore"):
        fin = np.isfinite(v)
    least = float(v[fin].min()) if fin.any() else np.nan
    return SweepTimes(header_ns, v[fin & view.keep], least)


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


def point_kinds(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> PointKinds:
    """Classify points (N,) by their coordinates (a time value never makes a point corrupt)."""
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
        if bool(finite.all()):  # the common case: no invalid return to sort by kind
            nan, pos, neg, invalid = (np.zeros(finite.shape, dtype=bool) for _ in range(4))
        else:
            nan = np.isnan(x) | np.isnan(y) | np.isnan(z)
            pos = ~nan & ((x == np.inf) | (y == np.inf) | (z == np.inf))
            neg = ~nan & ~pos & ((x == -np.inf) | (y == -np.inf) | (z == -np.inf))
            invalid = nan | pos | neg
        far = (np.abs(x) > MAX_COORD_M) | (np.abs(y) > MAX_COORD_M) | (np.abs(z) > MAX_COORD_M)
    corrupt = ~invalid & far
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


def decode_cloud(msg: Any, header_ns: int, conv: TimeConvention | None = None) -> Sweep:
    """Decode x, y, z (required), intensity and per-point time (under `conv`; None: the header
    stamp); drop invalid, corrupt and zero points (`point_kinds`)."""
    arr = _xyz_cloud(msg)
    names = arr.dtype.names or ()
    xyz = np.stack([arr[c].astype(np.float32) for c in ("x", "y", "z")], axis=1)
    kinds = point_kinds(xyz[:, 0], xyz[:, 1], xyz[:, 2])
    keep = kinds.keep
    if "intensity" in names:
        inten = arr["intensity"].astype(np.float32)
    else:
        inten = np.zeros(arr.size, dtype=np.float32)
    t_ns = _time_ns(arr, header_ns, conv)
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
            return decode_cloud(obj, stamp, row_convention(row))
    raise MissingDataError(
        f"{bag.name}: no {topic} message with log time {log_ns} ns and stamp {stamp} ns"
    )


TIME_COLUMNS = ("time_field", "time_unit", "time_reference")
"""The sweeps-table columns naming the topic's point-time convention ("" for none)."""


def convention_columns(conv: TimeConvention | None) -> dict[str, str]:
    """The sweeps-table columns of a convention ("" for none: header stamps)."""
    values = (conv.field, conv.unit, conv.reference) if conv else ("", "", "")
    return dict(zip(TIME_COLUMNS, values, strict=True))


def row_convention(row: Mapping[str, Any]) -> TimeConvention | None:
    """The point-time convention a sweeps-table row names; None without one (header stamps,
    also for rows read without those columns)."""
    field, unit, ref = (str(row.get(c) or "") for c in TIME_COLUMNS)
    if not field:
        return None
    return TimeConvention(field, "", unit, ref)  # type: ignore[arg-type]


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
    return CloudView(arr, point_kinds(arr["x"], arr["y"], arr["z"]))


def cloud_summary(msg: Any, header_ns: int,
                  conv: TimeConvention | None = None) -> tuple[PointCounts, int, int]:
    """Counts and (t_first_ns, t_last_ns) of the kept points, without materializing them."""
    return view_summary(cloud_view(msg), header_ns, conv)


PointTimesNs = tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]
"""(N,) int64 ns point times and (N,) bool usable, of every point of a cloud (`to_ns`)."""


def view_times(view: CloudView, header_ns: int,
               conv: TimeConvention | None) -> PointTimesNs | None:  # fmt: skip
    """`to_ns` of every point's time field under `conv`; None without a convention, without its
    field or without points. Read once for `view_summary` and `kept_points` (element-wise: the
    kept points' values are those `to_ns` gives for the kept points alone)."""
    if conv is None or conv.field not in (view.arr.dtype.names or ()) or view.arr.size == 0:
        return None
    return to_ns(view.arr[conv.field], header_ns, conv)


def view_summary(view: CloudView, header_ns: int, conv: TimeConvention | None = None,
                 times: PointTimesNs | None = None) -> tuple[PointCounts, int, int]:  # fmt: skip
    """Counts and (t_first_ns, t_last_ns) of the kept points of `view`.

    What the index needs from a sweep; the same drop rules as `decode_cloud`. Time span is
    (header_ns, header_ns) when no point is kept. `times`: `view_times` when already read.
    """
    arr, keep = view.arr, view.keep
    counts = view.kinds.counts()
    if counts.valid == 0:
        return counts, header_ns, header_ns
    t_ns = _time_ns(arr, header_ns, conv)[keep] if times is None else times[0][keep]
    return counts, int(t_ns.min()), int(t_ns.max())


def kept_points(view: CloudView, header_ns: int, conv: TimeConvention | None = None,
                times: PointTimesNs | None = None) -> SweepPoints:  # fmt: skip
    """The kept points of a PointCloud2 (the drop rules of `decode_cloud`) for the plausibility
    checks: xyz float64 m, time in s from `header_ns` under `conv` (None without a convention
    or its field; NaN for a value that cannot be read, which the checks flag), intensity and
    ring (None when the cloud lacks them). `times`: `view_times` when already read."""
    names = view.arr.dtype.names or ()
    every = bool(view.keep.all())
    kept = view.arr if every else view.arr[view.keep]  # no copy when all are kept
    xyz = np.stack([kept[c].astype(np.float64) for c in ("x", "y", "z")], axis=1)
    t_s = None
    if conv is not None and conv.field in names:
        if times is None:
            t_ns, ok = to_ns(kept[conv.field], header_ns, conv)
        else:
            t_ns, ok = times if every else (times[0][view.keep], times[1][view.keep])
        t_s = np.where(ok, (t_ns - header_ns).astype(np.float64) / 1e9, np.nan)
    inten = kept["intensity"].astype(np.float64) if "intensity" in names else None
    ring = kept["ring"].astype(np.int64) if "ring" in names else None
    return SweepPoints(xyz, t_s, inten, ring)
