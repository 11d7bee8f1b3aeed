"""Config sections of the data stages read from recordings (ingest with its topics, Hugging
Face and checks sub-sections, select). The strict base and what sections share:
`schemas.config_base`; the synth section: `schemas.config_synth`. The whole configuration, its
loading and hashing: `schemas.config` (which re-exports these names)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from pydantic import (
    Field,
    SerializerFunctionWrapHandler,
    model_serializer,
    model_validator,
)

from schemas.config_base import (
    StrictModel,
    camera_list,
    check_camera_names,
    drop_empty,
)
from schemas.errors import DataError
from schemas.names import check_name
from schemas.time_conventions import Reference, Unit


class CameraTopics(StrictModel):
    """One camera's own topics and frame; a key left unset takes its `topics` template."""

    image: str | None = Field(None, description="image topic (sensor_msgs/Image or "
                              "CompressedImage)")
    info: str | None = Field(None, description="sensor_msgs/CameraInfo topic")
    frame: str | None = Field(None, description="the camera's (optical) frame")


class PointTimeConfig(StrictModel):
    """A LiDAR's per-point time convention, declared (`schemas.time_conventions`)."""

    field: str = Field(description="the PointField holding each point's time")
    unit: Unit = Field(description="s, ms, us or ns")
    reference: Reference = Field(description="absolute (epoch), header (offset from the "
                                 "header stamp) or first_point (offset from the sweep's first "
                                 "point, which the header stamps)")


class LidarTopics(StrictModel):
    """One named LiDAR of `topics.lidars`: its PointCloud2 topic, frame and point-time."""

    topic: str = Field(description="PointCloud2 topic")
    frame: str = Field(description="the LiDAR's frame")
    point_time: Literal["auto", "none"] | PointTimeConfig = Field(
        "auto", description="per-point time, as `lidar_point_time`")


@dataclass(frozen=True)
class Lidar:
    """A LiDAR of the rig: its name (calibration sensor and sweeps-table `lidar`), topic,
    frame and point-time setting."""

    name: str
    topic: str
    frame: str
    point_time: Literal["auto", "none"] | PointTimeConfig


SINGLE_LIDAR = "lidar"
"""The name of the LiDAR the single-LiDAR keys (`lidar`, `lidar_frame`, ...) declare."""
_SINGLE_KEYS = ("lidar", "lidar_frame", "lidar_point_time")


class TopicsConfig(StrictModel):
    """ROS topics and frames; defaults are GrandTour's (SPEC §6)."""

    camera_image: str = Field("/boxi/hdr/{camera}/image_raw/compressed",
                              description="compressed image topic ({camera}: camera name)")
    camera_info: str = Field("/boxi/hdr/{camera}/camera_info",
                             description="camera calibration topic")
    lidar: str = Field("/boxi/hesai/points_undistorted",
                       description="LiDAR point cloud topic (motion-undistorted)")
    odometry: str = Field("/anymal/state_estimator/odometry", description="odometry topic")
    tf: str = Field("/tf", description="dynamic transform topic")
    tf_static: str = Field("/tf_static", description="static transform topic")
    base_frame: str = Field("base", description="the robot body frame of the odometry")
    odom_frame: str = Field("odom", description="the odometry (world) frame")
    lidar_frame: str = Field("hesai_lidar", description="the LiDAR's frame")
    lidar_point_time: Literal["auto", "none"] | PointTimeConfig = Field(
        "auto", description="the LiDAR's per-point time: auto (inferred per topic from the "
        "first sweeps, decision and evidence in checks.parquet), none (every point takes its "
        "header stamp) or {field, unit, reference}")
    camera_frame: str = Field("hdr_{camera}", description="a camera's frame")
    per_camera: dict[str, CameraTopics] = Field(
        default_factory=dict, description="a camera's own image topic, info topic and frame "
        "(by camera name; a key left out takes its template above)")
    lidars: dict[str, LidarTopics] = Field(
        default_factory=dict, description="several LiDARs by name, each with its topic, "
        "frame and point_time (instead of lidar, lidar_frame, lidar_point_time); every one "
        "is indexed, `select.lidar` names the one the views use (default: the first)")

    @model_serializer(mode="wrap")
    def _without_empty(self, handler: SerializerFunctionWrapHandler) -> dict[str, object]:
        return drop_empty(handler(self), "per_camera", "lidars")

    @model_validator(mode="after")
    def _one_lidar_form(self) -> TopicsConfig:
        both = sorted(set(_SINGLE_KEYS) & self.model_fields_set)
        if self.lidars and both:
            raise DataError(f"ingest.topics.lidars and ingest.topics.{both[0]} are both set: "
                            "declare the LiDARs one way (a LiDAR of `lidars` has its own "
                            "topic, frame and point_time)")
        topics = [v.topic for v in self.lidars.values()]
        dup = sorted({t for t in topics if topics.count(t) > 1})
        if dup:
            raise DataError(f"ingest.topics.lidars: two LiDARs share the topic {dup[0]!r}")
        return self

    def lidar_rig(self) -> list[Lidar]:
        """The LiDARs, in declared order: `lidars`, else the one of the single-LiDAR keys
        (named SINGLE_LIDAR)."""
        if not self.lidars:
            return [Lidar(SINGLE_LIDAR, self.lidar, self.lidar_frame, self.lidar_point_time)]
        return [Lidar(n, v.topic, v.frame, v.point_time) for n, v in self.lidars.items()]

    def _own(self, camera: str) -> CameraTopics:
        return self.per_camera.get(camera) or CameraTopics()

    def image_topic(self, camera: str) -> str:
        """The image topic of `camera` (its own, else the `camera_image` template)."""
        return self._own(camera).image or self.camera_image.format(camera=camera)

    def info_topic(self, camera: str) -> str:
        """The CameraInfo topic of `camera` (its own, else the `camera_info` template)."""
        return self._own(camera).info or self.camera_info.format(camera=camera)

    def frame_of(self, camera: str) -> str:
        """The frame of `camera` (its own, else the `camera_frame` template)."""
        return self._own(camera).frame or self.camera_frame.format(camera=camera)


class HfConfig(StrictModel):
    """GrandTour's Hugging Face layout: topic groups of `<mission>/data`, `<mission>/images`."""

    camera_group: str = Field("hdr_{camera}", description="store group and image folder of a "
                              "camera ({camera}: camera name)")
    lidar_group: str = Field("hesai_points_undistorted", description="store group of the "
                             "LiDAR scans")
    odometry_group: str = Field("anymal_state_odometry", description="store group of the "
                                "odometry")
    tf_group: str = Field("tf", description="store group of the static transforms")
    camera_groups: dict[str, str] = Field(default_factory=dict, description="a camera's own "
                                          "store group (by camera name; else camera_group)")
    tf_direction: Literal["child_from_parent", "parent_from_child"] = Field(
        "child_from_parent", description="what a `tf` entry maps: parent coordinates into the "
        "child frame (the maintainers' helper; default) or the ROS reading")

    @model_serializer(mode="wrap")
    def _without_empty(self, handler: SerializerFunctionWrapHandler) -> dict[str, object]:
        return drop_empty(handler(self), "camera_groups")

    def group(self, camera: str) -> str:
        """The store group (and image folder) of `camera`."""
        return self.camera_groups.get(camera) or self.camera_group.format(camera=camera)


class ChecksConfig(StrictModel):
    """Per-message plausibility checks of ingest (a ROS1 bag has no per-message checksum).

    A message failing one is rejected (its reason in the rejects table, naming file, topic and
    stamp), never cached. Defaults fit the GrandTour sensors (Hesai XT32 at 10 Hz, a legged
    robot's odometry) with wide margins; docs/benchmarks.md shows zero rejects on clean data.
    """

    enabled: bool = Field(True, description="run the checks below (false: none of them)")
    max_range_m: float = Field(500.0, gt=0, description="a LiDAR point farther than this (m) "
                               "is corrupt (Hesai XT32: 120 m)")
    max_intensity: float = Field(255.0, gt=0, description="intensity above this (or below 0) "
                                 "is corrupt (Hesai: 0-255)")
    max_ring: int = Field(127, ge=0, description="a ring number above this is corrupt "
                          "(XT32: 0-31; 127 allows 128-beam sensors)")
    ring_elevation_tol_deg: float = Field(3.0, gt=0, le=90, description="a point's elevation "
                                          "may differ this much from its ring's median")
    azimuth_tol_deg: float = Field(10.0, gt=0, le=180, description="a point's azimuth may "
                                   "differ this much from where the rotation puts it at its time")
    sweep_motion_m: float = Field(0.5, ge=0, description="how far the sensor may move during "
                                  "one sweep: widens both angle tolerances near the sensor")
    max_sweep_s: float = Field(0.25, gt=0, description="point times may lie this far (s) from "
                               "the sweep's header stamp (10 Hz: 0.1 s sweeps)")
    quat_norm_tol: float = Field(1e-6, gt=0, lt=1, description="an odometry quaternion whose "
                                 "norm differs more from 1 is corrupt (not re-normalized)")
    max_speed_m_s: float = Field(10.0, gt=0, description="odometry faster than this between "
                                 "a pose and its neighbours is a jump: that pose is rejected")
    image_step_z: float = Field(10.0, ge=0, description="an image whose colour steps from one "
                                "MCU row down against both neighbouring frames by more than "
                                "this robust z is damaged JPEG data (0: off)")
    image_blip_levels: float = Field(10.0, ge=0, description="an image offset by more grey "
                                     "levels than this against both neighbouring frames, which "
                                     "agree, is damaged JPEG data (0: off)")
    image_max_gap_s: float = Field(0.5, gt=0, description="frames farther apart (s) are not "
                                   "compared (no neighbour: the image check is skipped)")
    trust_checksums: bool = Field(True, description="skip the checks for a message whose "
                                  "bytes a verified chunk checksum vouches for (LZ4 chunks as "
                                  "`rosbag record --lz4` writes them); they catch flipped bytes "
                                  "that nothing else sees")
    calibration_messages: int = Field(10, ge=1, le=10_000, description="a check first judges "
                                      "this many messages of a topic without rejecting any; "
                                      "it is switched off for the topic when it finds more of "
                                      "them implausible than max_reject_share allows")
    max_reject_share: float = Field(0.02, ge=0, le=1, description="a check rejects at most "
                                    "this share of a topic's messages (at least one): past it, "
                                    "it stops rejecting and the messages are kept")


class IngestConfig(StrictModel):
    """Reading recordings and making the rectified, resized images."""

    recordings: list[Path] = Field(
        default_factory=list, description="mission folders; empty means synthesize"
    )
    cameras: list[str] = Field(default_factory=lambda: camera_list("front", "left", "right"),
                               description="cameras to ingest (any names; their topics and "
                               "frames: `topics.per_camera`, else the `{camera}` templates)")
    topics: TopicsConfig = Field(default_factory=TopicsConfig)
    format: Literal["auto", "rosbag", "hf-zarr", "kitti360"] = Field(
        "auto", description="input format of the mission folders (auto: detected per folder)")
    hf: HfConfig = Field(default_factory=HfConfig)
    out_height: int = Field(224, ge=14, le=4096, description="height of the rectified, "
                            "resized images (pixels, a multiple of the 14 px patch)")
    out_width: int = Field(336, ge=14, le=4096, description="width of the rectified, resized "
                           "images (pixels, a multiple of 14)")
    reduced_decode: bool = Field(True, description="decode JPEG at 1/2, 1/4, 1/8 when enough")
    rectify_balance: float = Field(0.0, ge=0.0, le=1.0, description="OpenCV balance of the "
                                   "new camera matrix: 0 keeps only valid pixels, 1 all of them")
    checks: ChecksConfig = Field(default_factory=ChecksConfig)

    @model_validator(mode="after")
    def _multiple_of_patch(self) -> IngestConfig:
        for key in ("out_height", "out_width"):
            value = getattr(self, key)
            if value % 14:
                raise DataError(f"{key}={value} must be a multiple of the 14 px patch")
        return self

    @model_validator(mode="after")
    def _camera_rig(self) -> IngestConfig:
        check_camera_names(list(self.cameras), "ingest.cameras")
        unknown = sorted(set(self.topics.per_camera) - set(self.cameras))
        if unknown:
            raise DataError(f"ingest.topics.per_camera names camera {unknown[0]!r}, which is "
                            f"not in ingest.cameras {list(self.cameras)}")
        by_topic: dict[str, str] = {}
        for cam in self.cameras:
            topic = self.topics.image_topic(cam)
            if topic in by_topic:
                raise DataError(f"cameras {by_topic[topic]!r} and {cam!r} share the image "
                                f"topic {topic!r}; give each its own "
                                "(ingest.topics.per_camera.<camera>.image)")
            by_topic[topic] = cam
        for lidar in self.topics.lidar_rig():
            check_name(lidar.name, "ingest.topics.lidars: LiDAR name")
            if lidar.name in self.cameras or lidar.name == "base":
                raise DataError(f"ingest.topics.lidars: LiDAR {lidar.name!r} has the name of "
                                "a camera or of the base: calibration rows are by sensor name")
        return self

    @model_validator(mode="after")
    def _unique_recording_names(self) -> IngestConfig:
        by_name: dict[str, list[str]] = {}
        for path in self.recordings:
            check_name(path.name, f"recording {str(path)!r}: its folder name")
            by_name.setdefault(path.name, []).append(str(path))
        clash = {n: p for n, p in by_name.items() if len(p) > 1}
        if clash:  # a recording is named by its folder: outputs would mix
            name, paths = next(iter(clash.items()))
            raise DataError(f"recordings share the folder name {name!r}: {', '.join(paths)}")
        return self


class SelectConfig(StrictModel):
    """Nearest-sweep selection and the odometry chain."""

    max_abs_dt_s: float = Field(0.1, gt=0, le=10, description="reject views beyond |dtau|")
    max_odom_gap_s: float = Field(0.25, gt=0, le=10, description="max interpolation gap")
    time_offset_s: float = Field(0.0, ge=-1, le=1, description="known camera clock minus "
                                 "LiDAR clock; image stamps are corrected by subtracting it")
    lidar: str | list[str] | None = Field(
        None, description="the LiDAR (a name of ingest.topics.lidars) whose nearest sweep each "
        "view takes and its packets carry (default: the first declared); a list of names "
        "merges their nearest sweeps into every packet, each point carried into the camera "
        "by its own sweep's pose and its cell's delta tau pooled from its own sweep's (the "
        "first of the list is the reference: its sweep decides whether a view is kept and "
        "gives the view's sweep stamp and delta tau)")

    @model_serializer(mode="wrap")
    def _without_empty(self, handler: SerializerFunctionWrapHandler) -> dict[str, object]:
        return drop_empty(handler(self), "lidar")

    @model_validator(mode="after")
    def _lidar_list(self) -> SelectConfig:
        if isinstance(self.lidar, list):
            if not self.lidar:
                raise DataError("select.lidar is an empty list: name one LiDAR or several")
            dup = sorted({n for n in self.lidar if self.lidar.count(n) > 1})
            if dup:
                raise DataError(f"select.lidar names the LiDAR {dup[0]!r} twice")
        return self

    def lidar_of(self, topics: TopicsConfig) -> Lidar:
        """The reference LiDAR: the one whose sweeps decide a view; DataError naming an
        unknown one."""
        return self.lidars_of(topics)[0]

    def lidars_of(self, topics: TopicsConfig) -> list[Lidar]:
        """The LiDARs the packets carry, the reference first (one unless `lidar` is a list);
        DataError naming an unknown one."""
        rig = topics.lidar_rig()
        if self.lidar is None:
            return rig[:1]
        by_name = {x.name: x for x in rig}
        names = [self.lidar] if isinstance(self.lidar, str) else self.lidar
        for name in names:
            if name not in by_name:
                raise DataError(f"select.lidar {name!r} is not a LiDAR of "
                                f"ingest.topics.lidars {list(by_name)}")
        return [by_name[n] for n in names]

    def merges(self) -> bool:
        """True when the packets merge the sweeps of several LiDARs."""
        return isinstance(self.lidar, list) and len(self.lidar) > 1
