"""The LiDAR part of the streaming pass (`pipeline.ingest.core.stream`): each PointCloud2 decoded
once for its counts, time span and plausibility verdicts, handed to its topic's gated pass
(`gated_pass.GatedPass`: the checks, the index, the rejects) or refused (`RowReject`).

A topic's first AUTO_SWEEPS sweeps are held until its point-time convention is decided on them
(`pipeline.ingest.checks.point_time`), then released in order under it.
"""

from __future__ import annotations

from typing import Any, Protocol

from pipeline.ingest.checks.point_time import AUTO_SWEEPS, PointTimes
from pipeline.ingest.checks.sweep_checks import sweep_problems
from pipeline.ingest.core.gated_pass import HELD, GatedPass, Held, Indexed
from pipeline.ingest.errors import RowReject
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
from schemas.recording_index import Reason


class SweepState(Protocol):
    """What the sweep handling reads and updates of the stream's state (`StreamState`)."""

    times: PointTimes
    lidar_topics: dict[str, str]
    checks: ChecksConfig
    dense_warned: set[str]
    notes: list[str]

    def trusted(self, msg: Message) -> bool:
        """A verified checksum vouches for the message and the config trusts it."""


def message_where(msg: Message) -> dict[str, object]:
    """The location columns of an index row."""
    return {"file": msg.file, "topic": msg.topic, "bag_time_ns": msg.bag_time_ns,
            "ordinal": msg.ordinal}  # fmt: skip


def sweep_message(msg: Message, obj: Any, stamp: int, st: SweepState,
                  gp: GatedPass) -> Indexed | Held:  # fmt: skip
    """One PointCloud2 decoded (`_index_sweep`); the first AUTO_SWEEPS of a topic are held
    (HELD) until its point-time convention is decided on them (`point_time`), then released."""
    held = st.times.hold(msg.topic, (msg, obj, stamp))
    if held is None:
        return _index_sweep(msg, obj, stamp, st, gp)
    if len(held) >= AUTO_SWEEPS:
        release_held(gp, st)
    return HELD


def release_held(gp: GatedPass, st: SweepState) -> None:
    """Decide the topic's point-time convention on its held sweeps and hand them, in order,
    to its gated pass's checks (a sweep that cannot be decoded is rejected)."""
    for msg, obj, stamp in st.times.release(gp.topic):
        try:
            done = _index_sweep(msg, obj, stamp, st, gp)
        except RowReject as err:
            gp.drop(err.file, stamp, err.reason, str(err))
            continue
        except (ValueError, AttributeError, KeyError) as err:
            gp.drop(msg.file, stamp, Reason.BAD_POINTCLOUD, str(err))
            continue
        gp.check(stamp, done)


def _index_sweep(msg: Message, obj: Any, stamp: int, st: SweepState,
                 gp: GatedPass) -> Indexed:  # fmt: skip
    """One PointCloud2's index row with its counts and time span, and its plausibility
    verdicts (none when its checks are off or a verified checksum vouches for it).

    The message's contract decides what is damage (`pointcloud.point_kinds`): invalid returns
    (NaN/Inf in any coordinate) and zero points are dropped and counted by kind, the sweep kept.
    A cloud that says it is dense yet holds invalid returns contradicts itself: the same, with
    one warning per topic. A sweep without a valid point is refused (RowReject `empty_sweep`);
    one with a corrupt point (a coordinate beyond MAX_COORD_M; never a time value) is damaged
    (`nonfinite_points`); one its topic's plausibility checks find impossible is damaged too
    (`bad_pointcloud`, by the gated pass). Point times follow the topic's decided convention.
    """
    view = cloud_view(obj)  # decoded once for the summary and the checks
    conv = st.times.convention(msg.topic)
    times = view_times(view, stamp, conv)  # read once for the summary and the checks
    c, t_first, t_last = view_summary(view, stamp, conv, times)
    if c.valid == 0:
        raise RowReject(Reason.EMPTY_SWEEP, msg.file, f"no valid points: {c.total} in message "
                        f"({c.kinds()}, {c.corrupt} corrupt)")  # fmt: skip
    if c.corrupt:
        raise RowReject(Reason.NONFINITE_POINTS, msg.file, f"{c.corrupt} of {c.total} points "
                        f"corrupt (a coordinate beyond {MAX_COORD_M:g} m): a damaged "
                        "message")  # fmt: skip
    if c.nonfinite and bool(getattr(obj, "is_dense", False)) and msg.topic not in st.dense_warned:
        st.dense_warned.add(msg.topic)
        st.notes.append(f"{msg.file}: {msg.topic}: the cloud at stamp {stamp} ns says is_dense "
                        f"but holds {c.nonfinite} invalid returns ({c.kinds()}): they are "
                        "dropped and counted, its sweeps kept (told once per topic)")
    row = {"lidar": st.lidar_topics[msg.topic], "stamp_ns": stamp, **message_where(msg),
           **sweep_counts(c), "t_first_ns": t_first, "t_last_ns": t_last,
           **convention_columns(conv)}  # fmt: skip
    if not st.checks.enabled:
        return Indexed(row, msg.file)
    trusted = st.trusted(msg)
    problems = {} if trusted else sweep_problems(kept_points(view, stamp, conv, times),
                                                 st.checks, gp.fitted().active)  # fmt: skip
    return Indexed(row, msg.file, problems, trusted=trusted)
