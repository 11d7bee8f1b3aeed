"""The bag family's ingest: every bag of a mission streamed once into the recording index.

Static calibration first (/tf_static and each camera's CameraInfo: images need their camera to
be rectified), then the streaming pass (`stream.stream_bag`) through the stamp gates,
plausibility checks and reject log, then the accounting. Peak memory does not grow with the
recording length: index rows are flushed in batches.
"""

from __future__ import annotations

import time
from pathlib import Path

import pyarrow as pa

from pipeline.ingest.calib.calib_track import CalibrationTrack
from pipeline.ingest.calib.camera import RawCamera, Rectifier, build_rectifier
from pipeline.ingest.calib.tf_tree import TfTree
from pipeline.ingest.checks.point_time import PointTimes
from pipeline.ingest.checks.rejects import Reject, warning_lines
from pipeline.ingest.core.stream import ImageSink, StreamState, Writers, finish_stream, stream_bag
from pipeline.ingest.index.ingest_result import IngestResult, index_writers, write_checks
from pipeline.ingest.sources.bags import BagFile, find_bags
from pipeline.ingest.sources.static import calibration_rows, did_you_mean, read_static, topic_owner
from pipeline.ingest.sources.tf_odometry import check_odometry_type
from schemas.config import IngestConfig
from schemas.errors import DataError
from schemas.recording_index import (
    ACCOUNTING,
    CALIBRATION,
    Reason,
    index_dir,
    table_path,
    write_index_table,
)


def ingest_bags(
    mission_dir: Path,
    out_dir: Path,
    cfg: IngestConfig,
    image_sink: ImageSink | None,
    rec: str,
) -> IngestResult:
    """Index a mission folder of bags: each bag streamed once through the gates and checks.

    Raises MissingTransformError (naming the missing chain) when a configured camera or the
    LiDAR is not connected to the base frame in /tf_static; recoverable faults become rejects.
    """
    t0 = time.perf_counter()
    idx = index_dir(out_dir, rec)
    bags = [BagFile(p, mission_dir) for p in find_bags(mission_dir)]
    try:
        check_topics(bags, cfg, mission_dir)
        calib = read_static(bags, cfg)
        write_index_table(  # fails before streaming when a TF chain is missing
            pa.Table.from_pylist(calibration_rows(calib, cfg), schema=CALIBRATION),
            CALIBRATION,
            table_path(idx, "calibration"),
        )
        with index_writers(idx) as out:
            state = _state(cfg, bags, calib.rectifiers, calib.tf, image_sink)
            for reject in calib.rejects:
                out.rejects.add(reject)
            for bag in bags:
                stream_bag(bag, state, out)
            finish_stream(state, out)
            _missing_topics(bags, state, out)
            write_checks(idx, state.check_rows())
            write_index_table(pa.Table.from_pylist(out.tally.rows(), schema=ACCOUNTING),
                              ACCOUNTING, table_path(idx, "accounting"))
    finally:
        for bag in bags:
            bag.close()
    return IngestResult(
        recording=rec,
        index_dir=idx,
        images=dict(state.frames),
        sweeps=out.sweeps.count,
        odometry=out.odometry.count,
        rejects=dict(out.rejects.counts),
        unaccounted=out.tally.unaccounted(),
        decode_reduction={c: r.reduction for c, r in calib.rectifiers.items()},
        seconds=time.perf_counter() - t0,
        warnings=warning_lines(out.rejects.notable, dict(out.rejects.counts),
                               table_path(idx, "rejects")) + calib.notes + state.warnings(),
        input_format=bag_format(bags),
        checks=state.check_rows(),
    )




def bag_format(bags: list[BagFile]) -> str:
    """The input format's name: `rosbag` (ROS1 and rosbag2), with the MCAP kinds read beside."""
    mcap = sorted({b.kind for b in bags if b.mcap is not None})
    return "+".join(mcap if len(mcap) == len({b.kind for b in bags}) else ["rosbag", *mcap])


def _state(
    cfg: IngestConfig,
    bags: list[BagFile],
    rectifiers: dict[str, Rectifier],
    tf: TfTree,
    sink: ImageSink | None,
) -> StreamState:
    """Streaming state from the config topics and the static calibration.

    Without an odometry topic in any bag, the odom-base edge of /tf is the odometry.
    """
    t = cfg.topics
    from_tf = topic_owner(bags, t.odometry) is None and topic_owner(bags, t.tf) is not None

    def build(cam: RawCamera) -> Rectifier:
        return build_rectifier(cam, (cfg.out_height, cfg.out_width), balance=cfg.rectify_balance,
                               reduced=cfg.reduced_decode)  # fmt: skip

    return StreamState(
        rectifiers=rectifiers,
        image_topics={t.image_topic(c): c for c in cfg.cameras},
        lidar_topics={x.topic: x.name for x in t.lidar_rig()},
        odom_topic=t.odometry,
        tf=tf,
        base_frame=t.base_frame,
        sink=sink,
        tf_odometry=(t.tf, t.odom_frame, t.base_frame) if from_tf else None,
        checks=cfg.checks,
        tracks={c: CalibrationTrack(c, r, build) for c, r in rectifiers.items()},
        info_topics={t.info_topic(c): c for c in cfg.cameras},
        times=PointTimes(per_topic={x.topic: x.point_time for x in t.lidar_rig()}),
    )


def check_topics(bags: list[BagFile], cfg: IngestConfig, mission_dir: Path) -> None:
    """ValueError naming the topic when no bag holds the calibration, the LiDAR or any camera,
    or when the odometry topic is of a type odometry is not read from.

    A damaged bag's topics are those of the connection records a forward scan can read.
    """
    known = set().union(*(b.topics() for b in bags))
    t = cfg.topics
    images = [t.image_topic(c) for c in cfg.cameras]
    lidars = [(x.topic, f"LiDAR {x.name!r}" if t.lidars else "LiDAR") for x in t.lidar_rig()]
    needs = [(t.tf_static, "calibration"), *lidars]
    if not known.intersection(images):
        needs.append((images[0], "camera image"))
    odom = topic_owner(bags, t.odometry)
    if odom is not None:
        check_odometry_type(t.odometry, odom.topics()[t.odometry], f"{mission_dir}: {odom.name}")
    for topic, what in needs:
        if topic not in known:
            damaged = [f"{b.name} ({b.damage})" for b in bags if b.damage]
            raise DataError(
                f"{mission_dir}: no bag holds the {what} topic {topic} "
                f"(bags: {', '.join(b.name for b in bags)}){did_you_mean(topic, bags)}"
                + (f"; damaged: {'; '.join(damaged)}" if damaged else "")
            )


def _missing_topics(bags: list[BagFile], st: StreamState, out: Writers) -> None:
    """One reject per configured topic that no bag holds, with a did-you-mean."""
    for topic in [*st.image_topics, *st.lidar_topics, st.odom_topic]:
        if st.seen.get(topic, 0) == 0 and topic_owner(bags, topic) is None:
            if topic == st.odom_topic and st.tf_odometry:
                continue  # odometry comes from /tf: reported once as such below
            out.rejects.add(Reject("", topic, 0, Reason.MISSING_TOPIC,
                                   f"no bag holds messages on {topic}"
                                   f"{did_you_mean(topic, bags)}"))  # fmt: skip
    if st.tf_odometry:
        out.rejects.add(Reject("", st.odom_topic, 0, Reason.MISSING_TOPIC,
                               f"no bag holds messages on {st.odom_topic}; odometry is taken "
                               f"from the {st.tf_odometry[1]}-{st.tf_odometry[2]} edge of "
                               f"{st.tf_odometry[0]}"))  # fmt: skip
