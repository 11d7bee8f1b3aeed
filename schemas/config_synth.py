"""The synth section: synthetic GrandTour recordings made when no real recording is
configured (`pipeline.synth`)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import (
    Field,
    SerializerFunctionWrapHandler,
    model_serializer,
    model_validator,
)

from schemas.config_base import (
    SceneName,
    SensorVariant,
    StrictModel,
    camera_list,
    check_camera_names,
    drop_empty,
    scene_list,
)
from schemas.errors import DataError

_SmallAngle = Annotated[float, Field(ge=-10, le=10)]
"""An injected mounting error angle (deg)."""
_SmallOffset = Annotated[float, Field(ge=-1, le=1)]
"""An injected mounting displacement (m)."""


class SynthConfig(StrictModel):
    """Synthetic GrandTour recordings made when no real recording is configured."""

    scenes: list[SceneName] = Field(default_factory=lambda: scene_list("corridor", "warehouse"),
                                    description="one synthetic mission per scene")
    seconds: float = Field(6.0, gt=0, le=3600, description="recording length in seconds")
    seed: int = Field(0, ge=0, description="random seed of the synthetic missions (their "
                      "names end in _s<seed>)")
    image_width: int = Field(480, ge=64, le=4096, description="raw camera width in pixels")
    image_height: int = Field(320, ge=64, le=4096, description="raw camera height in pixels")
    points_per_sweep: int = Field(16384, ge=64, le=131072, description="LiDAR points per sweep")
    camera_hz: float = Field(10.0, gt=0, le=60, description="camera frame rate")
    lidar_hz: float = Field(10.0, gt=0, le=40, description="LiDAR sweep rate")
    odom_hz: float = Field(20.0, gt=0, le=400, description="odometry rate")
    faults: list[
        Literal[
            "truncated_bag", "corrupt_jpeg", "nan_points", "empty_sweep", "missing_camera_info",
            "missing_tf_edge", "duplicate_stamps", "out_of_order_stamps", "camera_gap",
            "lidar_gap",
        ]
    ] = Field(default_factory=list, description="faults to inject (recorded in faults.json)")
    ros2: bool = Field(False, description="also write ROS2 MCAP copies of the bags")
    cameras: list[str] = Field(default_factory=lambda: camera_list("front", "left", "right"),
                               description="cameras the synthetic rig carries (front, left "
                               "and right face those ways; any other name is placed around "
                               "the rig in list order)")
    speed_mps: float = Field(0.8, gt=0, le=5, description="walking speed along the path")
    camera_lead_s: float = Field(0.3, ge=0, le=5, description="cameras start before the LiDAR")
    camera_jitter_ms: float = Field(8.0, ge=0, le=30, description="camera stamp jitter sigma")
    jpeg_quality: int = Field(90, ge=10, le=100, description="JPEG quality of the images")
    lidar_range_noise_m: float = Field(0.02, ge=0, le=1, description="range noise sigma")
    lidar_dropout: float = Field(0.02, ge=0, lt=1, description="random return dropout rate")
    lidar_max_range_m: float = Field(120.0, gt=1, le=500, description="LiDAR range limit (m)")
    depth_maps: bool = Field(True, description="write per-image ground-truth depth (zarr)")
    format: Literal["rosbag", "hf-zarr"] = Field(
        "rosbag", description="ROS1 bags, or GrandTour's Hugging Face layout (Zarr + JPEG)")
    hf_zarr_version: Literal[2, 3] = Field(2, description="Zarr format of an hf-zarr store")
    speed_variation: float = Field(0.0, ge=0, le=1, description="speed swings between "
                                   "(1 - a) and (1 + a) times speed_mps (0: constant speed)")
    speed_period_s: float = Field(8.0, gt=0, le=3600, description="period of the speed swing")
    yaw_rate_max_rps: float = Field(0.0, ge=0, le=3, description="peak rate of the body's "
                                    "turning on top of the path heading (rad/s; 0: none)")
    yaw_period_s: float = Field(6.0, gt=0, le=3600, description="period of the turning")
    camera_clock_offset_s: float = Field(0.0, ge=-1, le=1, description="camera clock minus "
                                         "LiDAR clock: image stamps = capture time + this")
    camera_extrinsic_error_deg: tuple[_SmallAngle, _SmallAngle, _SmallAngle] = Field(
        (0.0, 0.0, 0.0), description="[roll, pitch, yaw] (deg, each within +-10) of a camera "
        "mounting error: images are rendered with every camera turned by this rotation about "
        "its own optical axes (roll about z forward, pitch about x right, yaw about y down) "
        "while /tf_static keeps the nominal extrinsic")
    camera_extrinsic_offset_m: tuple[_SmallOffset, _SmallOffset, _SmallOffset] = Field(
        (0.0, 0.0, 0.0), description="(x, y, z) m (each within +-1) of a camera mounting "
        "displacement: images are rendered with every camera moved by this along its own "
        "optical axes (x right, y down, z forward) while /tf_static keeps the nominal "
        "extrinsic")
    variant: SensorVariant = Field("default", pattern=r"^[a-z0-9_]+$", description="sensor "
                                   "variant: another LiDAR, driver convention, odometry rate "
                                   "or camera model "
                                   "(pipeline/synth/variants.py; `m3gd synth --help`)")
    second_lidar: bool = Field(False, description="also carry a second LiDAR (topic "
                               "/livox/lidar, frame livox_frame; own bag): mounted "
                               "elsewhere and tilted down, its sweeps half a period after "
                               "the first's, so it sees other points at other times")

    @model_serializer(mode="wrap")
    def _without_empty(self, handler: SerializerFunctionWrapHandler) -> dict[str, object]:
        return drop_empty(handler(self), "second_lidar", "camera_extrinsic_offset_m")

    @model_validator(mode="after")
    def _camera_names(self) -> SynthConfig:
        check_camera_names(list(self.cameras), "synth.cameras")
        if self.second_lidar and self.format != "rosbag":
            raise DataError("synth.second_lidar is written as ROS1 bags only, not synth.format "
                            f"{self.format!r} (the Hugging Face layout has one LiDAR group)")
        return self
