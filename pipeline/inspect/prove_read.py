"""What inspect's proof reads from a recording, once for every candidate it judges.

A few views spread over the recording (`VIEWS`, from the reference LiDAR's span less
`EDGE_S` at either end): per view the first sweep of each LiDAR at or after the view's time
(decoded once, its edge points found once: `packets.edges.scan_edges`) and per camera the
first image at or after `LAG_NS` after that sweep's log time (less `IMAGE_LEAD_NS`),
rectified and downscaled to at most `WIDTH_PX` wide through the camera's first CameraInfo
(ingest's own rectifier, `pipeline.ingest.calib.camera`), kept grey. The pose candidates
are read from `/tf` and the odometry topics only within `WINDOW_NS` of each view (a long
recording costs what a short one does); the static tree from every `/tf_static` message.
Times are int64 ns: header stamps for sweeps, images and poses (the odometry clock), log
times to find messages.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from packets.edges import ScanEdges, scan_edges
from packets.poses import make_T, quat_to_rot
from pipeline.ingest.calib.camera import RawCamera, Rectifier, build_rectifier, camera_from_info
from pipeline.ingest.calib.tf_tree import TfTree
from pipeline.ingest.sources.bags import BagFile, stamp_ns
from pipeline.ingest.sources.image_decode import image_kind
from pipeline.ingest.sources.pointcloud import Sweep, decode_cloud
from pipeline.ingest.sources.tf_odometry import POSE_TYPES, pose_of
from pipeline.inspect import sample
from pipeline.inspect.model import Inspection
from pipeline.inspect.scan import open_bags
from schemas.errors import DataError
from schemas.time_conventions import NS_PER_UNIT, TimeConvention

F64 = npt.NDArray[np.float64]
T = TypeVar("T")
VIEWS = 12
"""Views per camera the proof scores (the verdict needs 8 with a null)."""
WIDTH_PX = 192
"""Images are rectified to at most this width (px)."""
LAG_NS = 200_000_000
"""A view pairs a sweep with an image this much later (ns): the candidate's odometry must
carry the sweep over the robot's motion in between, so a wrong pose source (a wheel turning
in place, another estimator's drift) moves the LiDAR's edges off the image's, where a pair
at one instant is blind to it."""
EDGE_S = 0.5
"""Views start and end this far (s) inside the reference LiDAR's span (the image `LAG_NS`
after its sweep; the verdict's clock search reads poses 0.2 s either side of it)."""
WINDOW_NS = 600_000_000
"""Poses are read this far (ns) either side of each view."""
IMAGE_LEAD_NS = 50_000_000
"""A view's image is the first at or after its sweep's log time plus `LAG_NS` less this
(ns)."""
TF_TYPE = "tf2_msgs/msg/TFMessage"


@dataclass(frozen=True)
class SweepView:
    """One decoded sweep: its topic, header stamp (ns), log time (ns; a layout without log
    times: the stamp) and edge points in its own frame; `first_ns`, `last_ns` its kept points'
    first and last time (ns) under the topic's inferred point-time convention (the stamp
    without one)."""

    topic: str
    stamp_ns: int
    log_ns: int
    edges: ScanEdges
    first_ns: int | None = None
    last_ns: int | None = None


@dataclass(frozen=True)
class ImageView:
    """One rectified image: header stamp (ns), grey (h, w) float64 0-255, K (3, 3) of it."""

    stamp_ns: int
    grey: F64
    K: F64


@dataclass
class ProofData:
    """Everything the proof scores, read once (module docstring): `sweeps[topic]` one per view
    (None where the LiDAR had none), `images[image topic]` one per view of the reference
    LiDAR (None where none was read), the static tree, every /tf message read (decoded) and
    each odometry topic's (stamp ns, T (4, 4)) samples; `first_xyz` each LiDAR's first sweep
    read (N, 3) float32 m, `step_rad` its azimuth step (`prove_judge.lidar_step`, once);
    `problems` what could not be read, one line each."""

    path: Path
    static: TfTree
    sweeps: dict[str, list[SweepView | None]] = field(default_factory=dict)
    images: dict[str, list[ImageView | None]] = field(default_factory=dict)
    tf: list[tuple[str, Any]] = field(default_factory=list)
    odometry: dict[str, list[tuple[int, F64]]] = field(default_factory=dict)
    first_xyz: dict[str, npt.NDArray[np.float32]] = field(default_factory=dict)
    step_rad: dict[str, float] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)


def view_times(first_ns: int, last_ns: int, n: int = VIEWS) -> list[int]:
    """`n` log times (ns) spread evenly from `first_ns` to `last_ns`, `EDGE_S` inside both
    ends; [] when the span is shorter than that."""
    lo, hi = first_ns + round(EDGE_S * 1e9), last_ns - round(EDGE_S * 1e9)
    if hi <= lo:
        return []
    return [int(t) for t in np.linspace(lo, hi, n).round().astype(np.int64)]


def sweep_view(topic: str, stamp: int, log_ns: int, sw: Sweep, data: ProofData) -> SweepView:
    """A decoded sweep as the proof keeps it: its edges, its points' first and last time; the
    LiDAR's first sweep read kept whole (`data.first_xyz`: its azimuth step)."""
    data.first_xyz.setdefault(topic, sw.xyz)
    first, last = ((int(sw.t_ns.min()), int(sw.t_ns.max())) if sw.t_ns.size
                   else (stamp, stamp))  # fmt: skip
    return SweepView(topic, stamp, log_ns, scan_edges(sw.xyz, sw.intensity), first, last)


def _sweep(bags: list[BagFile], topic: str, at_ns: int, data: ProofData,
           conv: TimeConvention | None) -> SweepView | None:  # fmt: skip
    """The first sweep of `topic` at or after `at_ns` (log time), decoded (point times under
    `conv`) and its edges."""
    got = sample.at(bags, topic, at_ns)
    if got is None:
        return None
    msg, cloud = got
    return sweep_view(topic, stamp_ns(cloud), msg.bag_time_ns,
                      decode_cloud(cloud, stamp_ns(cloud), conv), data)  # fmt: skip


def small_rectifier(cam: RawCamera) -> Rectifier:
    """The rectifier of a camera to at most WIDTH_PX wide."""
    w = min(WIDTH_PX, cam.width)
    return build_rectifier(cam, (max(1, round(cam.height * w / cam.width)), w))


def image_view(stamp: int, rgb: Any, rect: Rectifier) -> ImageView:
    """A rectified (h, w, 3) image as the proof keeps it: grey, with its K."""
    grey = np.asarray(rgb, np.float64).mean(axis=-1)
    return ImageView(stamp, grey, np.asarray(rect.K_out, np.float64))


def _rectifier(bags: list[BagFile], image_topic: str, info_topic: str) -> Rectifier:
    """The rectifier of a camera from its first CameraInfo, to at most WIDTH_PX wide."""
    got = next(sample.first(bags, info_topic, 1), None)
    if got is None:
        raise ValueError(f"{info_topic}: no CameraInfo message")
    return small_rectifier(camera_from_info(image_topic, got[1], info_topic))


def _image(bags: list[BagFile], topic: str, rect: Rectifier, at_ns: int) -> ImageView | None:
    """The first image of `topic` at or after `at_ns` (log time), rectified, grey."""
    got = sample.at(bags, topic, at_ns)
    if got is None:
        return None
    msg, img = got
    where = f"{topic} at {msg.bag_time_ns} ns"
    rgb = rect.remap(rect.decode_message(image_kind(msg.msgtype, img, topic), img, where))
    return image_view(stamp_ns(img), rgb, rect)


def _static(bags: list[BagFile], topics: list[str]) -> TfTree:
    """Every transform of the static TF topics."""
    tree = TfTree()
    for topic in topics:
        for _, msg in sample.first(bags, topic, 1000):
            tree.add_message(msg)
    return tree


def _windows(times: list[int]) -> list[tuple[int, int]]:
    """Merged [start, end] log-time windows (ns) of WINDOW_NS about each time."""
    out: list[tuple[int, int]] = []
    for t in sorted(times):
        lo, hi = t - WINDOW_NS, t + WINDOW_NS
        if out and lo <= out[-1][1]:
            out[-1] = (out[-1][0], hi)
        else:
            out.append((lo, hi))
    return out


def _poses(bags: list[BagFile], data: ProofData, tf_topics: list[str],
           odo_topics: dict[str, str], times: list[int]) -> None:  # fmt: skip
    """The /tf messages and odometry samples within the windows of `times`."""
    topics = [*tf_topics, *odo_topics]
    for lo, hi in _windows(times):
        for bag in [b for b in bags if set(topics) & set(b.topics())]:
            for raw in bag.messages([t for t in topics if t in bag.topics()], start=lo):
                if raw.bag_time_ns > hi:
                    break
                msg = bag.deserialize(raw)
                if raw.topic in odo_topics:
                    pose, _ = pose_of(odo_topics[raw.topic], msg)
                    p, q = pose.position, pose.orientation
                    T = make_T(quat_to_rot([q.x, q.y, q.z, q.w]), [p.x, p.y, p.z])
                    data.odometry.setdefault(raw.topic, []).append((stamp_ns(msg), T))
                else:
                    data.tf.append((raw.topic, msg))


def conventions(ins: Inspection) -> dict[str, TimeConvention | None]:
    """Each LiDAR topic's inferred point-time convention (None: its header stamp)."""
    out: dict[str, TimeConvention | None] = {}
    for c in ins.clouds:
        conv = c.convention
        ok = c.time_field and c.time_dtype and conv.unit in NS_PER_UNIT and conv.reference
        out[c.topic] = (TimeConvention(str(c.time_field), str(c.time_dtype),
                                       conv.unit, conv.reference)  # type: ignore[arg-type]
                        if ok else None)  # fmt: skip
    return out


def bag_proof_data(path: Path, ins: Inspection, lidars: list[str]) -> ProofData:
    """The proof's views of a bag, an MCAP file or a folder of them: views spread over the
    first of `lidars` (the reference), the other LiDARs' sweeps at the same times, every
    camera's images; problems named in `ProofData.problems`."""
    types = {t.topic: t.msgtype for t in ins.topics}
    stats = {t.topic: t for t in ins.topics}
    _, bags = open_bags(path)
    try:
        statics = [t for t in types if t.rstrip("/").endswith("tf_static")]
        data = ProofData(path, _static(bags, statics))
        ref = stats.get(lidars[0]) if lidars else None
        times = ([] if ref is None or ref.first_ns is None or ref.last_ns is None
                 else view_times(ref.first_ns, ref.last_ns))  # fmt: skip
        if not times:
            data.problems.append("the reference LiDAR's recording is too short for views")
            return data
        convs = conventions(ins)
        for topic in lidars:
            data.sweeps[topic] = [_or_none(data, _sweep, bags, topic, t, data, convs.get(topic))
                                  for t in times]  # fmt: skip
        _read_images(bags, ins, data)
        tf_topics = [t for t, ty in types.items() if ty.endswith("TFMessage") and t not in statics]
        odo = {t: ty for t, ty in types.items() if ty in POSE_TYPES}
        _poses(bags, data, tf_topics, odo, times)
        return data
    finally:
        for bag in bags:
            bag.close()


def _or_none(data: ProofData, read: Callable[..., T], *args: Any) -> T | None:
    """`read(*args)`, or None with the problem noted (a damaged message leaves its view out)."""
    try:
        return read(*args)
    except (DataError, ValueError) as err:
        data.problems.append(str(err))
        return None


def _read_images(bags: list[BagFile], ins: Inspection, data: ProofData) -> None:
    """Every camera's images at the reference LiDAR's views."""
    ref = next(iter(data.sweeps.values()))
    for cam in ins.cameras:
        if not cam.info_topic or cam.error:
            data.problems.append(f"camera {cam.image_topic}: no CameraInfo or unreadable")
            continue
        try:
            rect = _rectifier(bags, cam.image_topic, cam.info_topic)
            data.images[cam.image_topic] = [
                None if s is None else _or_none(data, _image, bags, cam.image_topic, rect,
                                                s.log_ns + LAG_NS - IMAGE_LEAD_NS)
                for s in ref]  # fmt: skip
        except (DataError, ValueError, OSError) as err:
            data.problems.append(f"camera {cam.image_topic}: {err}")
