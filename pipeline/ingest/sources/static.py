"""Static calibration of a mission: the /tf_static tree and each camera's CameraInfo.

Read before the streaming pass (images need their camera to be rectified): every /tf_static
message of every bag, and the first CameraInfo of each configured camera.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from packets.poses import F64
from pipeline.ingest.calib.camera import RawCamera, Rectifier, build_rectifier, camera_from_info
from pipeline.ingest.calib.tf_tree import TfTree
from pipeline.ingest.checks.rejects import Reject
from pipeline.ingest.errors import MissingTransformError
from pipeline.ingest.sources.bags import BagFile, stamp_ns
from schemas.config import IngestConfig
from schemas.errors import DataError
from schemas.recording_index import Reason


@dataclass
class StaticCalib:
    """TF tree, raw cameras and their rectifiers, and the rejects met while reading them."""

    tf: TfTree = field(default_factory=TfTree)
    cameras: dict[str, RawCamera] = field(default_factory=dict)
    rectifiers: dict[str, Rectifier] = field(default_factory=dict)
    rejects: list[Reject] = field(default_factory=list)
    frames: dict[str, str] = field(default_factory=dict)
    """Sensor -> TF frame taken from its messages' frame_id (the configured one is not in the
    tree); `notes` tell the user."""
    notes: list[str] = field(default_factory=list)


def topic_owner(bags: list[BagFile], topic: str) -> BagFile | None:
    """The first bag whose topic list holds `topic`."""
    return next((bag for bag in bags if topic in bag.topics()), None)


def did_you_mean(topic: str, bags: list[BagFile]) -> str:
    """'; did you mean X?' naming the topics of `bags` closest to `topic` ('' if none is)."""
    known = sorted(set().union(*(b.topics() for b in bags)) - {topic})
    close = difflib.get_close_matches(topic, known, n=2, cutoff=0.6)
    return f"; did you mean {' or '.join(close)}?" if close else ""


def _first_message(bags: list[BagFile], topic: str) -> tuple[BagFile, Any] | None:
    """The first decodable message of `topic` in any bag."""
    for bag in bags:
        if topic not in bag.topics():
            continue
        for msg in bag.messages([topic]):
            try:
                return bag, bag.deserialize(msg)
            except ValueError:
                continue
    return None


def read_static(bags: list[BagFile], cfg: IngestConfig) -> StaticCalib:
    """TF tree from /tf_static of all bags, and CameraInfo + rectifier per configured camera."""
    calib = StaticCalib()
    topic = cfg.topics.tf_static
    for bag in bags:
        if topic not in bag.topics():
            continue
        for msg in bag.messages([topic]):
            try:
                calib.tf.add_message(bag.deserialize(msg))
            except ValueError as err:
                calib.rejects.append(
                    Reject(msg.file, topic, msg.bag_time_ns, Reason.UNDECODABLE_MESSAGE, str(err))
                )
    if not calib.tf.frames:
        damaged = [f"{b.name} ({b.damage})" for b in bags if b.damage]
        raise DataError(
            f"no {topic} transform was read from any bag ({', '.join(b.name for b in bags)})"
            + (f"; damaged: {'; '.join(damaged)}" if damaged else "")
            + ": the calibration (GrandTour: <mission>_tf_minimal.bag) is missing or unreadable"
        )
    for camera in cfg.cameras:
        _read_camera(bags, cfg, camera, calib)
    _resolve_frames(bags, cfg, calib)
    _check_skipped_chains(bags, cfg, calib)
    return calib


def _resolve_frames(bags: list[BagFile], cfg: IngestConfig, calib: StaticCalib) -> None:
    """A sensor whose configured TF frame is not connected to the base frame takes the
    frame_id of its messages (CameraInfo, the first cloud) when that one is connected."""
    t = cfg.topics
    reach = set(calib.tf.connected(t.base_frame))
    want = {c: (t.frame_of(c), t.info_topic(c))
            for c in calib.cameras}  # fmt: skip
    want.update({x.name: (x.frame, x.topic) for x in t.lidar_rig()})
    for sensor, (frame, topic) in want.items():
        if frame in reach:
            continue
        found = _first_message(bags, topic)
        header = str(getattr(getattr(found[1], "header", None), "frame_id", "")).lstrip("/") \
            if found else ""
        if header and header in reach:
            calib.frames[sensor] = header
            calib.notes.append(f"{sensor}: TF frame {frame!r} (ingest.topics) is not in "
                               f"{t.tf_static}; using {header!r}, the frame_id of its "
                               f"messages on {topic}")  # fmt: skip


def _check_skipped_chains(bags: list[BagFile], cfg: IngestConfig, calib: StaticCalib) -> None:
    """Record (not raise) missing TF chains of cameras that are skipped for another reason."""
    owner = topic_owner(bags, cfg.topics.tf_static)
    for camera in cfg.cameras:
        if camera in calib.cameras:
            continue
        frame = cfg.topics.frame_of(camera)
        try:
            calib.tf.lookup(cfg.topics.base_frame, frame)
        except MissingTransformError as err:
            calib.rejects.append(Reject(owner.name if owner else "", cfg.topics.tf_static, 0,
                                        Reason.MISSING_TF_EDGE, str(err)))  # fmt: skip


def _read_camera(bags: list[BagFile], cfg: IngestConfig, camera: str, calib: StaticCalib) -> None:
    """Add one camera's model and rectifier, or a missing-camera_info reject."""
    info_topic = cfg.topics.info_topic(camera)
    found = _first_message(bags, info_topic)
    image_topic = cfg.topics.image_topic(camera)
    owner = topic_owner(bags, image_topic)
    if found is None:
        calib.rejects.append(
            Reject(
                owner.name if owner else "",
                info_topic,
                0,
                Reason.MISSING_CAMERA_INFO,
                f"no CameraInfo on {info_topic} in any bag; images of camera '{camera}' "
                f"on {image_topic} are not ingested{did_you_mean(info_topic, bags)}",
            )
        )
        return
    bag, msg = found
    try:
        cam = camera_from_info(camera, msg, f"{bag.name}: {info_topic}")
    except ValueError as err:
        calib.rejects.append(Reject(bag.name, info_topic, stamp_ns(msg), Reason.BAD_CAMERA_INFO,
                                    f"unusable CameraInfo: {err}; images of camera '{camera}' "
                                    f"on {image_topic} are not ingested"))  # fmt: skip
        return
    calib.cameras[camera] = cam
    calib.rectifiers[camera] = build_rectifier(
        cam,
        (cfg.out_height, cfg.out_width),
        balance=cfg.rectify_balance,
        reduced=cfg.reduced_decode,
    )


def sensor_frames(cfg: IngestConfig, cameras: list[str],
                  frames: dict[str, str] | None = None) -> dict[str, tuple[str, str]]:
    """Sensor name -> (TF frame, kind) for the configured cameras and every LiDAR; `frames`
    overrides the configured frame of a sensor (`StaticCalib.frames`)."""
    frames = frames or {}
    out = {c: (frames.get(c, cfg.topics.frame_of(c)), "camera")
           for c in cameras}  # fmt: skip
    for x in cfg.topics.lidar_rig():
        out[x.name] = (frames.get(x.name, x.frame), "lidar")
    return out


def base_transforms(calib: StaticCalib, cfg: IngestConfig) -> dict[str, F64]:
    """T_base_sensor (4, 4) for every required sensor; MissingTransformError naming the chain
    and the config keys that set its two ends."""
    base = cfg.topics.base_frame
    out = {}
    for name, (frame, _) in sensor_frames(cfg, sorted(calib.cameras), calib.frames).items():
        try:
            out[name] = calib.tf.lookup(base, frame)
        except MissingTransformError as err:
            raise MissingTransformError(f"{err}; {frame_keys_hint(calib.tf, cfg, name, frame)}"
                                        ) from err  # fmt: skip
    return out


def frame_key(cfg: IngestConfig, sensor: str) -> str:
    """The config key that sets the TF frame of `sensor` (a LiDAR or a camera name)."""
    if sensor in cfg.topics.lidars:
        return f"ingest.topics.lidars.{sensor}.frame"
    if sensor == "lidar" and not cfg.topics.lidars:
        return "ingest.topics.lidar_frame"
    own = cfg.topics.per_camera.get(sensor)
    if own is not None and own.frame:
        return f"ingest.topics.per_camera.{sensor}.frame"
    return (f"ingest.topics.per_camera.{sensor}.frame (else the template "
            "ingest.topics.camera_frame)")


def frame_keys_hint(tf: TfTree, cfg: IngestConfig, sensor: str, frame: str) -> str:
    """What to set when `frame` of `sensor` is not connected to the base frame: the base frame
    key alone when the base frame is in no transform, else it and the sensor's frame key."""
    base = cfg.topics.base_frame
    if base not in tf.frames:
        return (f"the base frame {base!r} is in no transform of /tf_static: set "
                "ingest.topics.base_frame to the robot's body frame (the child frame of the "
                f"odometry), one of the frames {frame!r} reaches")
    return (f"set ingest.topics.base_frame (now {base!r}) or {frame_key(cfg, sensor)} "
            f"(now {frame!r}) to frames that /tf_static connects")


def calibration_rows(calib: StaticCalib, cfg: IngestConfig) -> list[dict[str, object]]:
    """Calibration-table rows: cameras, the LiDAR, and every other frame connected to base."""
    base = cfg.topics.base_frame
    T = base_transforms(calib, cfg)
    rows: list[dict[str, object]] = []
    for name, (frame, kind) in sensor_frames(cfg, sorted(calib.cameras), calib.frames).items():
        row: dict[str, object] = _row(name, frame, kind, T[name])
        if kind == "camera":
            cam, rect = calib.cameras[name], calib.rectifiers[name]
            row.update(
                model=cam.model, width=cam.width, height=cam.height,
                K=cam.K.ravel().tolist(), D=cam.D.tolist(),
                out_width=cfg.out_width, out_height=cfg.out_height,
                K_out=rect.K_out.ravel().tolist(), decode_reduction=rect.reduction,
            )  # fmt: skip
        rows.append(row)
    sensors = sensor_frames(cfg, sorted(calib.cameras), calib.frames)
    named = {f for f, _ in sensors.values()} | set(sensors)  # a frame named as a sensor (a
    rows.extend(  # camera `hdr_front` on frame `hdr_front_optical`) would shadow its row
        _row(frame, frame, "frame", calib.tf.lookup(base, frame))
        for frame in calib.tf.connected(base)
        if frame not in named
    )
    return rows


def _row(sensor: str, frame: str, kind: str, T: F64) -> dict[str, object]:
    """A calibration row without camera fields."""
    return {
        "sensor": sensor, "frame_id": frame, "kind": kind,
        "T_base_sensor": np.asarray(T, dtype=np.float64).ravel().tolist(),
        "model": None, "width": None, "height": None, "K": None, "D": None,
        "out_width": None, "out_height": None, "K_out": None, "decode_reduction": None,
    }  # fmt: skip
