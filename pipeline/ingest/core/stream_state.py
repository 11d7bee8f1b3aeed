"""The state of the streaming pass (`stream`): the index writers, each topic's gated pass
(`gated_pass.GatedPass`: stamp gate, checks), the calibration tracks and point-time holds."""

from __future__ import annotations

from dataclasses import dataclass, field

from pipeline.ingest.calib.calib_track import CalibrationTrack
from pipeline.ingest.calib.camera import Rectifier
from pipeline.ingest.calib.tf_tree import TfTree
from pipeline.ingest.checks.check_fit import FitGate
from pipeline.ingest.checks.point_time import PointTimes
from pipeline.ingest.core.gated_pass import GatedPass
from pipeline.ingest.core.sinks import ImageSink
from pipeline.ingest.sources.bags import Message
from schemas.config import ChecksConfig


@dataclass
class StreamState:
    """Each topic's gated pass and per-camera frame counters across bags."""

    rectifiers: dict[str, Rectifier]
    image_topics: dict[str, str]
    lidar_topics: dict[str, str]  # PointCloud2 topic -> LiDAR name
    odom_topic: str
    tf: TfTree
    base_frame: str
    sink: ImageSink | None
    tf_odometry: tuple[str, str, str] | None = None  # (/tf topic, odom frame, base frame)
    checks: ChecksConfig = field(default_factory=ChecksConfig)
    passes: dict[str, GatedPass] = field(default_factory=dict)  # topic -> its gated pass
    frames: dict[str, int] = field(default_factory=dict)
    seen: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    dense_warned: set[str] = field(default_factory=set)
    tracks: dict[str, CalibrationTrack] = field(default_factory=dict)
    info_topics: dict[str, str] = field(default_factory=dict)  # CameraInfo topic -> camera
    info_last: dict[str, object] = field(default_factory=dict)  # camera -> `stream.info_key`
    unsupported: set[str] = field(default_factory=set)
    times: PointTimes = field(default_factory=PointTimes)

    def trusted(self, msg: Message) -> bool:
        """True when a verified checksum vouches for the message's bytes and the config
        trusts it: its per-message checks are skipped (they look for flipped bytes)."""
        return msg.verified and self.checks.trust_checksums

    def check_rows(self) -> list[dict[str, object]]:
        """Checks-table rows: every check on every topic it ran on."""
        fits = self._fits()
        return [row for t in sorted(fits) for row in fits[t].rows()] + self.times.rows()

    def warnings(self) -> list[str]:
        """What the stream told the user: self-contradicting clouds, checks that do not fit."""
        tracks = [n for c in sorted(self.tracks) for n in self.tracks[c].notes]
        fits = self._fits()
        return self.notes + tracks + self.times.notes + [n for t in sorted(fits)
                                                         for n in fits[t].notes]  # fmt: skip

    def _fits(self) -> dict[str, FitGate]:
        """The fitted checks of every topic that reached them."""
        return {t: p.checked for t, p in self.passes.items() if p.checked is not None}

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

