"""`inspect_recording`: the whole inspection of a ROS1 / ROS2 recording or an HF mission."""

from __future__ import annotations

import time
from pathlib import Path

from pipeline.ingest.bags import BagFile
from pipeline.ingest.hf.store import detect_format
from pipeline.ingest.tf_odometry import POSE_TYPES
from pipeline.inspect import sample
from pipeline.inspect.cameras import IMAGE_TYPES, INFO_TYPE, camera_report, pair_info
from pipeline.inspect.clouds import CLOUD_TYPE, cloud_report
from pipeline.inspect.model import Inspection, TopicStats
from pipeline.inspect.rates import timing
from pipeline.inspect.scan import TopicTimes, file_sizes, open_bags, recording_times
from pipeline.inspect.tf import tf_report
from schemas.errors import DataError, MissingInputError


def inspect_recording(path: Path) -> Inspection:
    """Inspect a `.bag` or `.mcap` file, a ROS2 bag folder, a mission folder of bags or an HF
    mission.

    MissingInputError (naming `path`) when there is nothing to read; DataError for a bag that
    cannot be opened.
    """
    began = time.perf_counter()
    if not path.exists():
        raise MissingInputError(f"{path}: no such file or folder")
    if path.is_dir() and detect_format(path) == "hf-zarr":
        from pipeline.inspect.hf import inspect_hf

        return inspect_hf(path, began)
    mission, bags = open_bags(path)
    try:
        return _inspect_bags(path, mission, bags, began)
    finally:
        for bag in bags:
            bag.close()


def topic_stats(topic: str, tt: TopicTimes, files: tuple[str, ...]) -> TopicStats:
    """A topic's row from its index times."""
    if tt.times is None:
        return TopicStats(topic, tt.msgtype, tt.count, files=files)
    t = timing(tt.times)
    return TopicStats(topic, tt.msgtype, tt.count, t.first_ns, t.last_ns, t.rate_hz, t.period_s,
                      t.n_gaps, t.gaps, files)  # fmt: skip


def _inspect_bags(path: Path, mission: Path, bags: list[BagFile], began: float) -> Inspection:
    """The inspection of opened bags."""
    times = recording_times(bags)
    topics = tuple(topic_stats(t, tt, files) for t, (tt, files) in sorted(times.items()))
    types = {t.topic: t.msgtype for t in topics}
    tf, _ = tf_report(bags, types)
    clouds = tuple(cloud_report(bags, t) for t, m in types.items() if m == CLOUD_TYPE)
    infos = [t for t, m in types.items() if m == INFO_TYPE]
    cameras = tuple(
        camera_report(bags, t, m, (info := pair_info(t, infos)),
                      times[info][0].times if info is not None else None)
        for t, m in types.items() if m in IMAGE_TYPES)  # fmt: skip
    notes = [f"{b.name}: {b.damage}" for b in bags if b.damage]
    notes += [f"{t.topic}: the index gives no message times (no rate or gaps)"
              for t in topics if t.first_ns is None and t.count]  # fmt: skip
    kinds = {b.kind for b in bags}
    return Inspection(str(path), "+".join(sorted(kinds)), file_sizes(mission, bags), topics, tf,
                      clouds, cameras, odometry(bags, types), tuple(notes),
                      time.perf_counter() - began)  # fmt: skip


def odometry(bags: list[BagFile], types: dict[str, str]) -> tuple[tuple[str, str, str], ...]:
    """(topic, frame_id, child_frame_id) of the first message of every odometry topic
    (`tf_odometry.POSE_TYPES`; child '' for a pose type without one), nav_msgs/Odometry
    first."""
    out = []
    for topic in sorted((t for t, m in types.items() if m in POSE_TYPES),
                        key=lambda t: (POSE_TYPES.index(types[t]), t)):  # fmt: skip
        try:
            got = next(sample.first(bags, topic, 1), None)
        except DataError:
            got = None
        if got is not None:
            msg = got[1]
            out.append((topic, str(msg.header.frame_id).lstrip("/"),
                        str(getattr(msg, "child_frame_id", "")).lstrip("/")))  # fmt: skip
    return tuple(out)
