"""The LiDAR part of the streaming pass (`pipeline.ingest.core.stream`): each PointCloud2 decoded
once for its counts, time span and plausibility checks, and indexed or rejected.

A topic's first AUTO_SWEEPS sweeps are held until its point-time convention is decided on them
(`pipeline.ingest.checks.point_time`), then released in order under it.
"""

from __future__ import annotations

from typing import Any, Protocol

from pipeline.ingest.checks.check_fit import FitGate, Release
from pipeline.ingest.checks.point_time import AUTO_SWEEPS, PointTimes
from pipeline.ingest.checks.rejects import Reject, RejectLog, Tally
from pipeline.ingest.checks.sweep_checks import SWEEP_CHECKS, sweep_problems
from pipeline.ingest.sources.bags import Message
from pipeline.ingest.sources.pointcloud import (
    MAX_COORD_M,
    cloud_view,
    convention_columns,
    kept_points,
    sweep_counts,
    view_summary,
    view_times,
)
from schemas.config import ChecksConfig
from schemas.recording_index import IndexTableWriter, Reason


class SweepState(Protocol):
    """What the sweep handling reads and updates of the stream's state (`StreamState`)."""

    times: PointTimes
    lidar_topics: dict[str, str]
    checks: ChecksConfig
    dense_warned: set[str]
    notes: list[str]

    def fit(self, topic: str, checks: tuple[str, ...]) -> FitGate:
        """The plausibility checks of `topic`."""

    def trusted(self, msg: Message) -> bool:
        """A verified checksum vouches for the message and the config trusts it."""


class SweepOut(Protocol):
    """Where sweeps go (`stream.Writers`): the sweeps table, the reject log, the tally."""

    sweeps: IndexTableWriter
    rejects: RejectLog

    @property
    def tally(self) -> Tally:
        """Messages read, kept and rejected per (bag file, topic)."""


def message_where(msg: Message) -> dict[str, object]:
    """The location columns of an index row."""
    return {"file": msg.file, "topic": msg.topic, "bag_time_ns": msg.bag_time_ns,
            "ordinal": msg.ordinal}  # fmt: skip


def sweep_message(msg: Message, obj: Any, stamp: int, st: SweepState,
                  out: SweepOut) -> bool | None:  # fmt: skip
    """Index one PointCloud2 (`_index_sweep`); the first AUTO_SWEEPS of a topic are held (None)
    until its point-time convention is decided on them (`point_time`), then released."""
    held = st.times.hold(msg.topic, (msg, obj, stamp))
    if held is None:
        return _index_sweep(msg, obj, stamp, st, out)
    if len(held) >= AUTO_SWEEPS:
        release_held(msg.topic, st, out)
    return None


def release_held(topic: str, st: SweepState, out: SweepOut) -> None:
    """Decide `topic`'s point-time convention on its held sweeps and index them, in order."""
    for msg, obj, stamp in st.times.release(topic):
        try:
            ok = _index_sweep(msg, obj, stamp, st, out)
        except (ValueError, AttributeError, KeyError) as err:
            out.rejects.add(Reject(msg.file, msg.topic, stamp, Reason.BAD_POINTCLOUD, str(err)))
            continue
        if ok:
            out.tally.kept[(msg.file, msg.topic)] += 1


def _index_sweep(msg: Message, obj: Any, stamp: int, st: SweepState,
                 out: SweepOut) -> bool | None:  # fmt: skip
    """Index one PointCloud2 with its counts and time span; False when rejected, None when its
    topic's checks hold it (decided later, `release_sweep`).

    The message's contract decides what is damage (`pointcloud.point_kinds`): invalid returns
    (NaN/Inf in any coordinate) and zero points are dropped and counted by kind, the sweep kept.
    A cloud that says it is dense yet holds invalid returns contradicts itself: the same, with
    one warning per topic. A sweep without a valid point is rejected (`empty_sweep`); one with
    a corrupt point (a coordinate beyond MAX_COORD_M; never a time value) is damaged
    (`nonfinite_points`); one its topic's plausibility checks find impossible is damaged too
    (`bad_pointcloud`). Point times follow the topic's decided convention.
    """
    view = cloud_view(obj)  # decoded once for the summary and the checks
    conv = st.times.convention(msg.topic)
    times = view_times(view, stamp, conv)  # read once for the summary and the checks
    c, t_first, t_last = view_summary(view, stamp, conv, times)
    if c.valid == 0:
        detail = (f"no valid points: {c.total} in message ({c.kinds()}, {c.corrupt} "
                  "corrupt)")  # fmt: skip
        out.rejects.add(Reject(msg.file, msg.topic, stamp, Reason.EMPTY_SWEEP, detail))
        return False
    if c.corrupt:
        detail = (f"{c.corrupt} of {c.total} points corrupt (a coordinate beyond "
                  f"{MAX_COORD_M:g} m): a damaged message")  # fmt: skip
        out.rejects.add(Reject(msg.file, msg.topic, stamp, Reason.NONFINITE_POINTS, detail))
        return False
    if c.nonfinite and bool(getattr(obj, "is_dense", False)) and msg.topic not in st.dense_warned:
        st.dense_warned.add(msg.topic)
        st.notes.append(f"{msg.file}: {msg.topic}: the cloud at stamp {stamp} ns says is_dense "
                        f"but holds {c.nonfinite} invalid returns ({c.kinds()}): they are "
                        "dropped and counted, its sweeps kept (told once per topic)")
    row = {"lidar": st.lidar_topics[msg.topic], "stamp_ns": stamp, **message_where(msg),
           **sweep_counts(c), "t_first_ns": t_first, "t_last_ns": t_last,
           **convention_columns(conv)}  # fmt: skip
    if not st.checks.enabled:
        release_sweep(Release((msg, row)), out, count=False)
        return True
    gate = st.fit(msg.topic, SWEEP_CHECKS)
    trusted = st.trusted(msg)
    problems = {} if trusted else sweep_problems(kept_points(view, stamp, conv, times),
                                                 st.checks, gate.active)  # fmt: skip
    for rel in gate.push((msg, row), problems, trusted):
        release_sweep(rel, out)
    return None


def release_sweep(rel: Release, out: SweepOut, count: bool = True) -> None:
    """Index a sweep let go by its topic's checks (counted kept when `count`), or reject it."""
    msg, row = rel.item
    if rel.rejected_by is not None:
        check, problem = rel.rejected_by
        out.rejects.add(Reject(msg.file, msg.topic, row["stamp_ns"], Reason.BAD_POINTCLOUD,
                               f"{problem} ({check}): a damaged message"))  # fmt: skip
        return
    out.sweeps.append({"sweep": out.sweeps.count, **row})
    if count:
        out.tally.kept[(msg.file, msg.topic)] += 1
