"""LiDAR per-point time conventions: the declared table, the decode, and `auto` inference.

A PointCloud2 may carry a per-point time field. Its convention is (field, dtype, unit, reference):

- unit: `s`, `ms`, `us`, `ns` (NS_PER_UNIT);
- reference: `absolute` (time since the Unix epoch: t = v), `header` (offset from the message's
  header stamp: t = header + v; the header may stamp any instant of the sweep, its end
  included, so offsets may be negative), `first_point` (offset from the sweep's first point,
  which the header stamps: t = header + v, the earliest offset is 0; Ouster `t`, Livox
  `offset_time`). `header` and `first_point` decode alike; the evidence tells them apart by
  where the header stamp lies.

CONVENTIONS is every (dtype, unit, reference) a dtype can hold (`held`): the largest value
written (an epoch stamp up to MAX_EPOCH_S for `absolute`, an offset up to MAX_OFFSET_S
otherwise) fits the dtype, and is resolved to RESOLUTION_NS or finer (an integer's step is one
unit; a float's is its spacing at that value); `header` needs a signed dtype (the header stamps
the sweep's end: offsets <= 0). The synthetic generator writes exactly this table.

`infer` decides a topic's convention from the first sweeps' evidence, never from a value's
magnitude alone: the span of the decoded point times within a sweep against the sweep period
(the median step of consecutive header stamps), and for `absolute` the agreement of the decoded
times with the header stamp. Units are a factor 1000 apart and SPAN_RATIO's window is narrower
than that, so at most one unit fits. Where none fits the points take the header stamp
(`PointTimeDecision.convention` None). Pure: no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
import numpy.typing as npt

Unit = Literal["s", "ms", "us", "ns"]
Reference = Literal["absolute", "header", "first_point"]
TimeDtype = Literal["float32", "float64", "uint32", "uint64", "int64"]
Source = Literal["auto", "config", "none"]

UNITS: tuple[Unit, ...] = get_args(Unit)
REFERENCES: tuple[Reference, ...] = get_args(Reference)
DTYPES: tuple[TimeDtype, ...] = get_args(TimeDtype)
NS_PER_UNIT: dict[str, int] = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}

TIME_FIELDS = ("timestamp", "t", "time", "ts", "offset_time")
"""Field names read as a per-point time, first present wins (`auto`; a config names its own)."""
FIELD_OF: dict[str, str] = {"absolute": "timestamp", "header": "time", "first_point": "t"}
"""The field the generator writes for each reference."""

MAX_EPOCH_S = 4_102_444_800
"""2100-01-01 in Unix seconds: the largest absolute stamp a convention must hold."""
MAX_OFFSET_S = 1.0
"""The largest offset within a sweep a relative convention must hold (a 1 Hz LiDAR)."""
RESOLUTION_NS = 1_000
"""A convention must resolve point times to 1 us (at 10 Hz: 0.0036 deg of rotation)."""
SPAN_RATIO = (0.03, 3.0)
"""A fitting unit makes the median point-time span of a sweep this many sweep periods (a 11 deg
sector .. three accumulated sweeps): a window narrower than the factor 1000 between units."""
HEADER_OFFSET_MAX = 1.0
"""A fitting absolute unit puts the header stamp within this many periods of the sweep's
points (median over the sampled sweeps)."""
AUTO_SWEEPS = 8
"""Sweeps of a topic `auto` reads for its evidence."""
INT64_SAFE = 9.2e18
"""Decoded times beyond this (ns) do not fit int64: such a point takes the header stamp."""

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True)
class TimeConvention:
    """One per-point time convention: field name, dtype (numpy name), unit, reference."""

    field: str
    dtype: str
    unit: Unit
    reference: Reference

    @property
    def name(self) -> str:
        """`<dtype>_<unit>_<reference>`, e.g. `float64_ns_absolute` (the synth variant's tail)."""
        return f"{self.dtype}_{self.unit}_{self.reference}"

    @property
    def relative(self) -> bool:
        """True for `header` and `first_point` (t = header + value)."""
        return self.reference != "absolute"

    def describe(self) -> str:
        """One phrase, e.g. 'timestamp float64 ns absolute'."""
        return f"{self.field} {self.dtype} {self.unit} {self.reference}"


def _largest(unit: str, reference: str) -> float:
    """The largest value (in `unit`) a convention must hold."""
    top_s = MAX_EPOCH_S if reference == "absolute" else MAX_OFFSET_S
    return top_s * 1e9 / NS_PER_UNIT[unit]


def held(dtype: str, unit: str, reference: str) -> str | None:
    """Why `dtype` cannot hold the convention (one phrase), or None when it can."""
    dt = np.dtype(dtype)
    top = _largest(unit, reference)
    if reference == "header" and dt.kind == "u":
        return "header offsets are negative (the header stamps the sweep's end): unsigned"
    if dt.kind == "f":
        step_ns = float(np.spacing(dt.type(top))) * NS_PER_UNIT[unit]
    else:
        if top > np.iinfo(dt).max:
            return f"{top:.3g} {unit} overflows {dtype}"
        step_ns = float(NS_PER_UNIT[unit])
    if step_ns > RESOLUTION_NS:
        return f"resolves {step_ns:.3g} ns at {top:.3g} {unit}, coarser than {RESOLUTION_NS} ns"
    return None


CONVENTIONS: tuple[TimeConvention, ...] = tuple(
    TimeConvention(FIELD_OF[r], d, u, r)
    for d in DTYPES for u in UNITS for r in REFERENCES if held(d, u, r) is None
)  # fmt: skip
"""Every convention the declared dtypes can hold (the reader's and the generator's table)."""

DRIVERS: dict[str, TimeConvention] = {
    "hesai (GrandTour)": TimeConvention("timestamp", "float64", "s", "absolute"),
    "livox_ros_driver2": TimeConvention("timestamp", "float64", "ns", "absolute"),
    "livox (custom msg)": TimeConvention("offset_time", "uint32", "ns", "first_point"),
    "ouster": TimeConvention("t", "uint32", "ns", "first_point"),
    "velodyne": TimeConvention("time", "float32", "s", "first_point"),
    "velodyne (stamp at sweep end)": TimeConvention("time", "float32", "s", "header"),
}
"""Drivers known to write a convention of the table (documentation; tests check each is held)."""


def by_name(name: str) -> TimeConvention:
    """The table's convention `<dtype>_<unit>_<reference>` (KeyError when it holds none)."""
    found = {c.name: c for c in CONVENTIONS}
    return found[name]


# ---------------------------------------------------------------------------- decode / encode


def to_ns(values: npt.NDArray[np.generic], header_ns: int, conv: TimeConvention
          ) -> tuple[I64, npt.NDArray[np.bool_]]:  # fmt: skip
    """(N,) int64 ns point times of raw field `values` (N,) under `conv`, and (N,) bool: the
    value was usable. An unusable value (NaN, Inf, a time beyond int64) takes `header_ns`."""
    scale = NS_PER_UNIT[conv.unit]
    base = header_ns if conv.relative else 0
    v = np.asarray(values)
    with np.errstate(all="ignore"):
        v64 = v.astype(np.float64)
        ok = np.abs(v64 * scale + base) < INT64_SAFE  # False for NaN and Inf
        every = bool(ok.all())
        if v.dtype.kind == "f":
            v64 = v64 if every else np.where(ok, v64, 0.0)
            whole = np.floor(v64)  # split: float64 epoch seconds keep their sub-us digits
            ns = whole.astype(np.int64) * scale + np.rint((v64 - whole) * scale).astype(np.int64)
        else:
            ns = (v if every else np.where(ok, v, 0)).astype(np.int64) * scale
    ns += base
    out = ns if every else np.where(ok, ns, header_ns).astype(np.int64)
    return out, ok


def from_ns(t_ns: npt.ArrayLike, header_ns: int, conv: TimeConvention) -> npt.NDArray[np.generic]:
    """The raw field values (N,) in `conv.dtype` that `to_ns` reads back as `t_ns` (N,) int64
    (exactly for integers, to the float's resolution for floats): the generator's writer."""
    t = np.asarray(t_ns, dtype=np.int64) - (header_ns if conv.relative else 0)
    scale = NS_PER_UNIT[conv.unit]
    dt = np.dtype(conv.dtype)
    if dt.kind != "f":
        return (t // scale).astype(dt)
    whole, rest = np.divmod(t, scale)
    return (whole.astype(np.float64) + rest.astype(np.float64) / scale).astype(dt)


# ---------------------------------------------------------------------------- inference


@dataclass(frozen=True)
class SweepTimes:
    """One sampled sweep: its header stamp (int64 ns), the finite time values (n,) float64 of
    its points with valid coordinates, and the least finite value of any of its points."""

    header_ns: int
    values: F64
    least: float


@dataclass(frozen=True)
class TimeEvidence:
    """What a convention makes of the sampled sweeps: sweeps sampled, sweep period (median step
    of consecutive header stamps, ns; None with fewer than two distinct stamps), median
    point-time span over the period, median distance of the header stamp from the sweep's
    points in periods, and whether every sweep's least offset is 0."""

    sweeps: int
    period_ns: float | None = None
    span_ratio: float | None = None
    header_offset: float | None = None
    first_at_zero: bool = False

    def fits(self) -> bool:
        """The span is SPAN_RATIO periods and the header within HEADER_OFFSET_MAX of it."""
        if self.span_ratio is None or self.header_offset is None:
            return False
        lo, hi = SPAN_RATIO
        return lo <= self.span_ratio <= hi and self.header_offset <= HEADER_OFFSET_MAX

    def line(self) -> str:
        """One line of the numbers."""
        if self.period_ns is None:
            return f"{self.sweeps} sweep(s), no sweep period (fewer than 2 distinct stamps)"
        span = "n/a" if self.span_ratio is None else f"{self.span_ratio:.3g}"
        off = "n/a" if self.header_offset is None else f"{self.header_offset:.3g}"
        return (f"{self.sweeps} sweeps, period {self.period_ns / 1e6:.4g} ms, span/period "
                f"{span}, header {off} periods from the points, least offset "
                f"{'0' if self.first_at_zero else 'not 0'}")  # fmt: skip


@dataclass(frozen=True)
class PointTimeDecision:
    """A topic's point-time convention (None: every point takes its header stamp), who decided
    (`auto`, `config`, `none`), the evidence, and a one-line reason."""

    convention: TimeConvention | None
    source: Source
    evidence: TimeEvidence
    reason: str = ""

    def line(self) -> str:
        """One line for the checks table and the report."""
        what = self.convention.describe() if self.convention else "none (header stamps)"
        tail = f"; {self.reason}" if self.reason else ""
        return f"{self.source}: {what}; evidence: {self.evidence.line()}{tail}"


def sweep_period(sweeps: Sequence[SweepTimes]) -> float | None:
    """Median positive step (ns) of consecutive header stamps, None without one."""
    stamps = np.array([s.header_ns for s in sweeps], dtype=np.int64)
    steps = np.diff(stamps)
    steps = steps[steps > 0]
    return float(np.median(steps)) if steps.size else None


def evidence(sweeps: Sequence[SweepTimes], unit: str, relative: bool) -> TimeEvidence:
    """The evidence for reading the sampled sweeps in `unit`, relative or absolute."""
    period = sweep_period(sweeps)
    used = [s for s in sweeps if s.values.size]
    zero = bool(sweeps) and all(s.least == 0.0 for s in sweeps)
    if period is None or not used:
        return TimeEvidence(len(sweeps), period, first_at_zero=zero)
    scale = float(NS_PER_UNIT[unit])
    spans, offsets = [], []
    for s in used:
        h = float(s.header_ns)
        with np.errstate(all="ignore"):
            lo = float(s.values.min()) * scale + (h if relative else 0.0)
            hi = float(s.values.max()) * scale + (h if relative else 0.0)
        spans.append(hi - lo)
        offsets.append(max(lo - h, h - hi, 0.0))
    ratio, off = float(np.median(spans)) / period, float(np.median(offsets)) / period
    if not (math.isfinite(ratio) and math.isfinite(off)):
        return TimeEvidence(len(sweeps), period, first_at_zero=zero)
    return TimeEvidence(len(sweeps), period, ratio, off, zero)


def _reference(ev: TimeEvidence, relative: bool) -> Reference:
    """absolute; first_point when every sweep's least offset is 0, else header."""
    if not relative:
        return "absolute"
    return "first_point" if ev.first_at_zero else "header"


def infer(field: str | None, dtype: str, sweeps: Sequence[SweepTimes]) -> PointTimeDecision:
    """`auto`: the convention of a topic's time `field` (numpy `dtype`) from its first sweeps.

    Every unit, absolute and relative, is scored by its evidence; of those that fit and that
    `dtype` can hold (`held`: a field too narrow or too coarse for a time cannot carry one, so
    a fit there is noise), the one whose span is closest to one sweep period wins. None fits:
    convention None, with why.
    """
    if field is None:
        return PointTimeDecision(None, "none", TimeEvidence(len(sweeps)),
                                 f"no time field ({', '.join(TIME_FIELDS)})")  # fmt: skip
    if np.dtype(dtype).kind not in "fiu":
        return PointTimeDecision(None, "none", TimeEvidence(len(sweeps)),
                                 f"field {field!r} has non-numeric dtype {dtype}")  # fmt: skip
    scored, unheld = [], []
    for unit in UNITS:
        for relative in (False, True):
            ev = evidence(sweeps, unit, relative)
            if not ev.fits():
                continue
            assert ev.span_ratio is not None
            why = held(dtype, unit, _reference(ev, relative))
            if why is None:
                scored.append((abs(math.log(ev.span_ratio)), unit, relative, ev))
            else:
                unheld.append(f"{unit}: {why}")
    if not scored and unheld:
        return PointTimeDecision(None, "none", evidence(sweeps, "ns", True),
                                 f"field {field!r} ({dtype}) cannot hold a point time "
                                 f"({'; '.join(unheld)})")  # fmt: skip
    if not scored:
        ev = evidence(sweeps, "ns", True)
        return PointTimeDecision(None, "none", ev, f"no unit or reference of {field!r} "
                                 f"({dtype}) fits the sweeps' span and header stamps")
    _, unit, relative, ev = min(scored, key=lambda s: s[0])
    conv = TimeConvention(field, dtype, unit, _reference(ev, relative))
    return PointTimeDecision(conv, "auto", ev)


def configured(conv: TimeConvention, sweeps: Sequence[SweepTimes]) -> PointTimeDecision:
    """A convention set in the config, with the evidence of the sampled sweeps for it (a
    reason when the evidence does not fit it: the config still decides)."""
    ev = evidence(sweeps, conv.unit, conv.relative)
    reason = "" if ev.fits() or not sweeps else "the evidence does not fit it"
    return PointTimeDecision(conv, "config", ev, reason)
