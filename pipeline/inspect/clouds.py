"""Per PointCloud2 topic: the point layout and the point-time evidence of its first sweeps.

The layout is the message's own (`fields`, `point_step`, `is_dense`, endianness), decoded with
ingest's reader (`pipeline.ingest.sources.pointcloud.cloud_dtype` / `cloud_array`).
The time evidence
is raw: the time field's values (min, max, non-finite count) against each sweep's header
stamp, the sweep period from the sampled header stamps, the values read in each unit, and what
what the reader makes of them under the decided convention. `decide_convention` chooses it
with ingest's inference (`schemas.time_conventions.infer`, the same evidence rules).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from pipeline.ingest.sources.bags import BagFile, stamp_ns
from pipeline.ingest.sources.pointcloud import (
    POINTFIELD_TYPES,
    cloud_array,
    cloud_dtype,
    cloud_view,
    time_field_named,
    view_summary,
)
from pipeline.inspect import sample
from pipeline.inspect.model import CloudReport, Convention, PointField, SweepTime, UnitReading
from schemas.errors import DataError
from schemas.time_conventions import PointTimeDecision, SweepTimes, infer
from schemas.time_conventions import sweep_period as period_ns

CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"
SWEEPS_SAMPLED = 5
"""Consecutive sweeps read per topic (from the first)."""
UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
NS = 1_000_000_000


def fields_of(msg: Any) -> tuple[PointField, ...]:
    """The PointFields of a PointCloud2 as written (unknown datatypes kept, dtype '?')."""
    return tuple(PointField(str(f.name), int(f.datatype), POINTFIELD_TYPES.get(int(f.datatype),
                                                                              "?"),
                            int(f.offset), int(f.count)) for f in msg.fields)  # fmt: skip


def sweep_time(msg: Any, log_ns: int, field: str | None,
               decision: PointTimeDecision | None = None) -> SweepTime:
    """Point-time evidence of one sweep and what the reader makes of it under `decision`
    (DataError when its layout cannot be decoded)."""
    header = stamp_ns(msg)
    arr = cloud_array(msg)
    raw_min = raw_max = None
    nonfinite = 0
    if field is not None and arr.size:
        v = np.asarray(arr[field], dtype=np.float64).reshape(arr.size, -1)[:, 0]
        ok = np.isfinite(v)
        nonfinite = int((~ok).sum())
        if ok.any():
            raw_min, raw_max = float(v[ok].min()), float(v[ok].max())
    conv = decision.convention if decision else None
    counts, t0, t1 = view_summary(cloud_view(msg), header, conv)
    return SweepTime(header, log_ns, int(arr.size), raw_min, raw_max, nonfinite, t0, t1,
                     counts.corrupt)  # fmt: skip


def unit_readings(sweeps: tuple[SweepTime, ...]) -> tuple[UnitReading, ...]:
    """The sampled time values read in each unit of UNITS (empty without time values)."""
    rows = [s for s in sweeps if s.raw_min is not None and s.raw_max is not None]
    if not rows:
        return ()
    lo = np.array([s.raw_min for s in rows], dtype=np.float64)
    hi = np.array([s.raw_max for s in rows], dtype=np.float64)
    head_s = np.array([s.header_ns / NS for s in rows], dtype=np.float64)
    return tuple(UnitReading(u, float(np.median((hi - lo) * k)),
                             float(np.median(lo * k - head_s)), float(np.median(lo * k)))
                 for u, k in UNITS.items())  # fmt: skip


def sweep_period(sweeps: tuple[SweepTime, ...]) -> float | None:
    """Median interval (s) of the sampled header stamps in time order, as ingest measures it
    (`schemas.time_conventions.sweep_period`: positive steps; None without one)."""
    ordered = sorted(s.header_ns for s in sweeps)
    step = period_ns([SweepTimes(t, np.zeros(0), np.nan) for t in ordered])
    return None if step is None else step / NS


def decide(report: CloudReport) -> PointTimeDecision:
    """ingest's `auto` decision on the sampled sweeps' evidence (their min and max values)."""
    samples = [SweepTimes(s.header_ns, np.array([s.raw_min, s.raw_max], dtype=np.float64),
                          s.raw_min) if s.raw_min is not None and s.raw_max is not None
               else SweepTimes(s.header_ns, np.zeros(0), np.nan) for s in report.sweeps]
    dtype = np.dtype(report.time_dtype).name if report.time_dtype else "V"
    return infer(report.time_field, dtype, samples)


def decide_convention(report: CloudReport) -> Convention:
    """How the point times of `report`'s topic are read: ingest's `auto` inference on the
    evidence (`schemas.time_conventions`), with its numbers in the note."""
    d = decide(report)
    c = d.convention
    if c is None:
        return Convention("auto: no convention fits", None, None,
                          f"every point takes the header stamp ({d.reason}; "
                          f"{d.evidence.line()})")  # fmt: skip
    return Convention("auto (schemas.time_conventions)", c.unit, c.reference, d.evidence.line())


def cloud_report(bags: list[BagFile], topic: str) -> CloudReport:
    """Layout and time evidence of `topic` from its first SWEEPS_SAMPLED messages."""
    try:
        first = list(sample.first(bags, topic, SWEEPS_SAMPLED))
    except DataError as err:
        return _empty(topic, str(err))
    if not first:
        return _empty(topic, "no message could be read")
    msg0 = first[0][1]
    fields = fields_of(msg0)
    error = None
    try:
        dtype = cloud_dtype(msg0)
        names = tuple(dtype.names or ())
        tfield = time_field_named(names)
        tdtype = dtype.fields[tfield][0].base.str if tfield and dtype.fields else None
        sweeps = tuple(sweep_time(m, raw.bag_time_ns, tfield) for raw, m in first)
        probe = CloudReport(topic, "", (), 0, 0, 0, 0, False, False, tfield, tdtype, sweeps,
                            None, (), Convention("", None, None))  # fmt: skip
        decision = decide(probe)
        sweeps = tuple(sweep_time(m, raw.bag_time_ns, tfield, decision) for raw, m in first)
    except DataError as err:
        tfield, tdtype, sweeps, error = None, None, (), str(err)
    report = CloudReport(
        topic, str(msg0.header.frame_id), fields, int(msg0.point_step), int(msg0.row_step),
        int(msg0.width), int(msg0.height), bool(msg0.is_dense), bool(msg0.is_bigendian),
        tfield, tdtype, sweeps, sweep_period(sweeps), unit_readings(sweeps),
        Convention("", None, None), error)  # fmt: skip
    return replace(report, convention=decide_convention(report))


def _empty(topic: str, error: str) -> CloudReport:
    """A report of a topic whose messages could not be read."""
    return CloudReport(topic, "", (), 0, 0, 0, 0, False, False, None, None, (), None, (),
                       Convention("unread", None, None), error)  # fmt: skip
