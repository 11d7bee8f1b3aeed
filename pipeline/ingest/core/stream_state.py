"""The state of the streaming pass (`stream`): the index writers, per-topic gates, checks and
calibration tracks, and the records handed between its handlers (images in order, held
images)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from packets.poses import F64
from pipeline.ingest.calib.calib_track import CalibrationTrack
from pipeline.ingest.calib.camera import Rectifier
from pipeline.ingest.calib.tf_tree import TfTree
from pipeline.ingest.checks.check_fit import FitGate
from pipeline.ingest.checks.gate import TopicGate
from pipeline.ingest.checks.image_checks import Cells
from pipeline.ingest.checks.image_drift import IMAGE_CHECKS, DriftHold
from pipeline.ingest.checks.point_time import PointTimes
from pipeline.ingest.checks.pose_checks import JumpFilter
from pipeline.ingest.checks.rejects import RejectLog, Tally
from pipeline.ingest.sources.bags import Message
from schemas.config import ChecksConfig
from schemas.recording_index import IndexTableWriter


class CameraImage(NamedTuple):
    """One rectified output image, in stamp order per camera.

    frame: 0-based index among the camera's accepted images; stamp_ns: header stamp (int64 ns);
    image: (out_h, out_w, 3) uint8 RGB; K_out: (3, 3) float64 intrinsics of `image`.
    """

    camera: str
    frame: int
    stamp_ns: int
    image: npt.NDArray[np.uint8]
    K_out: F64


ImageSink = Callable[[CameraImage], None]


@dataclass
class Writers:
    """The streamed index tables and the reject log."""

    images: IndexTableWriter
    sweeps: IndexTableWriter
    odometry: IndexTableWriter
    rejects: RejectLog
    damage: IndexTableWriter

    @property
    def tally(self) -> Tally:
        """Messages read, kept and rejected per (bag file, topic)."""
        return self.rejects.tally


@dataclass
class StreamState:
    """Per-topic stamp gates and per-camera frame counters across bags."""

    rectifiers: dict[str, Rectifier]
    image_topics: dict[str, str]
    lidar_topics: dict[str, str]  # PointCloud2 topic -> LiDAR name
    odom_topic: str
    tf: TfTree
    base_frame: str
    sink: ImageSink | None
    tf_odometry: tuple[str, str, str] | None = None  # (/tf topic, odom frame, base frame)
    checks: ChecksConfig = field(default_factory=ChecksConfig)
    gates: dict[str, TopicGate] = field(default_factory=dict)
    jumps: JumpFilter | None = None
    drift: DriftHold | None = None  # the image_drift check's held images (`images()`)
    frames: dict[str, int] = field(default_factory=dict)
    seen: dict[str, int] = field(default_factory=dict)
    fits: dict[str, FitGate] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    dense_warned: set[str] = field(default_factory=set)
    tracks: dict[str, CalibrationTrack] = field(default_factory=dict)
    info_topics: dict[str, str] = field(default_factory=dict)  # CameraInfo topic -> camera
    info_last: dict[str, object] = field(default_factory=dict)  # camera -> `stream.info_key`
    unsupported: set[str] = field(default_factory=set)
    times: PointTimes = field(default_factory=PointTimes)

    def fit(self, topic: str, checks: tuple[str, ...]) -> FitGate:
        """The plausibility checks of `topic` (`check_fit`)."""
        if topic not in self.fits:
            self.fits[topic] = FitGate(topic, checks, self.checks.calibration_messages,
                                       self.checks.max_reject_share)  # fmt: skip
        return self.fits[topic]

    def trusted(self, msg: Message) -> bool:
        """True when a verified checksum vouches for the message's bytes and the config
        trusts it: its per-message checks are skipped (they look for flipped bytes)."""
        return msg.verified and self.checks.trust_checksums

    def check_rows(self) -> list[dict[str, object]]:
        """Checks-table rows: every check on every topic it ran on."""
        rows = [row for topic in sorted(self.fits) for row in self.fits[topic].rows()]
        return rows + self.times.rows()

    def warnings(self) -> list[str]:
        """What the stream told the user: self-contradicting clouds, checks that do not fit."""
        tracks = [n for c in sorted(self.tracks) for n in self.tracks[c].notes]
        fits = [n for topic in sorted(self.fits) for n in self.fits[topic].notes]
        return self.notes + tracks + self.times.notes + fits

    def images(self) -> DriftHold:
        """The image_drift check's held images, by camera (`checks.image_drift`)."""
        if self.drift is None:
            self.drift = DriftHold(self.checks, lambda held: self.fit(
                held.msg.topic, IMAGE_CHECKS).active("image_drift"))  # fmt: skip
        return self.drift

    def jump_filter(self) -> JumpFilter | None:
        """The odometry jump filter (None when the checks are off)."""
        if self.jumps is None and self.checks.enabled:
            self.jumps = JumpFilter(self.checks.max_speed_m_s)
        return self.jumps

    def gate(self, topic: str) -> TopicGate:
        """The stamp gate of `topic`."""
        return self.gates.setdefault(topic, TopicGate())

    def wanted(self) -> set[str]:
        """Topics to stream: images of cameras that can be rectified, LiDAR, odometry."""
        images = {t for t, c in self.image_topics.items() if c in self.rectifiers}
        infos = {t for t, c in self.info_topics.items() if c in self.tracks}
        tf = {self.tf_odometry[0]} if self.tf_odometry else set()
        return images | infos | set(self.lidar_topics) | {self.odom_topic} | tf

    def rectifier_at(self, camera: str, stamp: int) -> Rectifier | str | None:
        """The camera's rectifier at `stamp` (its CameraInfo then), why there is none usable
        (a string), or None when the camera has no CameraInfo at all."""
        track = self.tracks.get(camera)
        return track.at(stamp) if track is not None else self.rectifiers.get(camera)


@dataclass(frozen=True)
class HeldImage:
    """A decoded, rectified image waiting for its next frame to be judged (`image_drift`):
    its message, stamp (ns), output image, JPEG size and cells."""

    msg: Message
    stamp_ns: int
    image: npt.NDArray[np.uint8]
    jpeg_bytes: int
    cells: Cells | None
    K_out: F64


POSE_CHECKS = ("quat_norm", "pose_jump")
