"""Run configuration: the YAML contract, validated by pydantic.

Every section is a strict model (unknown keys are errors). `load_config` turns a
validation failure into one line naming the file, the key and the value.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, ClassVar, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from schemas.errors import DataError
from schemas.layout import OutputLayout
from schemas.modes import PacketMode
from schemas.names import check_name

CONFIG_VERSION = 1

SceneName = Literal["corridor", "warehouse", "forest", "plaza"]
CameraName = Literal["front", "left", "right"]


def _scenes(*names: SceneName) -> list[SceneName]:
    """A typed list of scene names (a default factory)."""
    return list(names)


def _cameras(*names: CameraName) -> list[CameraName]:
    """A typed list of camera names (a default factory)."""
    return list(names)


DEVICE_PATTERN = r"^(auto|cpu|mps|cuda(:[0-9]+)?)$"
"""auto (CUDA when available, else CPU), cpu, cuda, cuda:N, mps."""


class StrictModel(BaseModel):
    """Base for config sections: unknown keys and type coercions are refused."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    not_in_key: ClassVar[frozenset[str]] = frozenset()
    """Fields that say where or how work runs, not what it computes: left out of cache keys."""


SensorVariant = Literal[
    "default", "vlp16", "rings_firing_order", "rings_reversed", "no_ring", "livox",
    "missing_nan", "missing_x_nan", "missing_zero", "missing_inf", "dense", "dense_with_nan",
    "time_u32_ns", "merged", "frames", "odom_50hz", "odom_400hz", "plumb_bob",
    "rational_polynomial",
]
"""Names of the synthetic sensor variants (`pipeline.synth.variants.VARIANTS`)."""


class SynthConfig(StrictModel):
    """Synthetic GrandTour recordings made when no real recording is configured."""

    scenes: list[SceneName] = Field(default_factory=lambda: _scenes("corridor", "warehouse"))
    seconds: float = Field(6.0, gt=0, le=3600, description="recording length in seconds")
    seed: int = Field(0, ge=0)
    image_width: int = Field(480, ge=64, le=4096, description="raw camera width in pixels")
    image_height: int = Field(320, ge=64, le=4096, description="raw camera height in pixels")
    points_per_sweep: int = Field(16384, ge=64, le=131072)
    camera_hz: float = Field(10.0, gt=0, le=60)
    lidar_hz: float = Field(10.0, gt=0, le=40)
    odom_hz: float = Field(20.0, gt=0, le=400)
    faults: list[
        Literal[
            "truncated_bag", "corrupt_jpeg", "nan_points", "empty_sweep", "missing_camera_info",
            "missing_tf_edge", "duplicate_stamps", "out_of_order_stamps", "camera_gap",
            "lidar_gap",
        ]
    ] = Field(default_factory=list, description="faults to inject (recorded in faults.json)")
    ros2: bool = Field(False, description="also write ROS2 MCAP copies of the bags")
    cameras: list[CameraName] = Field(default_factory=lambda: _cameras("front", "left", "right"))
    speed_mps: float = Field(0.8, gt=0, le=5, description="walking speed along the path")
    camera_lead_s: float = Field(0.3, ge=0, le=5, description="cameras start before the LiDAR")
    camera_jitter_ms: float = Field(8.0, ge=0, le=30, description="camera stamp jitter sigma")
    jpeg_quality: int = Field(90, ge=10, le=100)
    lidar_range_noise_m: float = Field(0.02, ge=0, le=1, description="range noise sigma")
    lidar_dropout: float = Field(0.02, ge=0, lt=1, description="random return dropout rate")
    lidar_max_range_m: float = Field(120.0, gt=1, le=500)
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
    variant: SensorVariant = Field("default", description="sensor variant: another LiDAR, "
                                   "driver convention, odometry rate or camera model "
                                   "(pipeline/synth/variants.py; `m3gd synth --help`)")


class TopicsConfig(StrictModel):
    """ROS topics and frames; defaults are GrandTour's (SPEC §6)."""

    camera_image: str = "/boxi/hdr/{camera}/image_raw/compressed"
    camera_info: str = "/boxi/hdr/{camera}/camera_info"
    lidar: str = "/boxi/hesai/points_undistorted"
    odometry: str = "/anymal/state_estimator/odometry"
    tf: str = "/tf"
    tf_static: str = "/tf_static"
    base_frame: str = "base"
    odom_frame: str = "odom"
    lidar_frame: str = "hesai_lidar"
    camera_frame: str = "hdr_{camera}"


class HfConfig(StrictModel):
    """GrandTour's Hugging Face layout: topic groups of `<mission>/data`, `<mission>/images`."""

    camera_group: str = "hdr_{camera}"
    lidar_group: str = "hesai_points_undistorted"
    odometry_group: str = "anymal_state_odometry"
    tf_group: str = "tf"
    tf_direction: Literal["child_from_parent", "parent_from_child"] = Field(
        "child_from_parent", description="what a `tf` entry maps: parent coordinates into the "
        "child frame (the maintainers' helper; default) or the ROS reading")


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
    cameras: list[CameraName] = Field(default_factory=lambda: _cameras("front", "left", "right"))
    topics: TopicsConfig = Field(default_factory=TopicsConfig)
    format: Literal["auto", "rosbag", "hf-zarr"] = Field(
        "auto", description="input format of the mission folders (auto: detected per folder)")
    hf: HfConfig = Field(default_factory=HfConfig)
    out_height: int = Field(224, ge=14, le=4096)
    out_width: int = Field(336, ge=14, le=4096)
    reduced_decode: bool = Field(True, description="decode JPEG at 1/2, 1/4, 1/8 when enough")
    rectify_balance: float = Field(0.0, ge=0.0, le=1.0)
    checks: ChecksConfig = Field(default_factory=ChecksConfig)

    @model_validator(mode="after")
    def _multiple_of_patch(self) -> IngestConfig:
        for key in ("out_height", "out_width"):
            value = getattr(self, key)
            if value % 14:
                raise DataError(f"{key}={value} must be a multiple of the 14 px patch")
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


class PacketsConfig(StrictModel):
    """LiDAR packets (eqs. 8-10)."""

    mode: PacketMode = "full"
    min_depth_m: float = Field(0.1, gt=0, le=100)
    front_surface: bool = False
    front_margin_m: float = Field(0.1, gt=0, description="front-surface margin behind each "
                                  "cell's nearest point, plus front_margin_rel times its depth")
    front_margin_rel: float = Field(1.5, ge=0, le=10, description="relative part of the "
                                    "front-surface margin (0: the fixed margin front_margin_m); "
                                    "chosen on ground truth, docs/tradeoffs.md")
    items: Literal["auto", "recording", "shard_row"] = Field(
        "auto", description="one task per recording (each sweep encoded once), per shard row "
        "(more parallel tasks; a sweep shared by two rows is encoded twice), or auto: whole "
        "recordings, split into shard rows only where that shortens the schedule on the "
        "run's workers")


class EncodersConfig(StrictModel):
    """Frozen encoders; the defaults are the embedded weight-free ones."""

    image: Literal["patch", "da3"] = "patch"
    image_channels: int = Field(768, ge=1, le=8192)
    da3_weights: Path | None = None
    allow_random_init: bool = False
    point: Literal["fpfh", "utonia"] = "fpfh"
    point_channels: int = Field(1224, ge=1, le=8192)
    utonia_weights: Path | None = None
    seed: int = Field(0, ge=0)
    device: str = Field("cpu", pattern=DEVICE_PATTERN, description="where the frozen image "
                        "encoder runs (DA3 batches of images; the patch encoder is numpy)")
    worker_resources: str = Field(
        "", pattern=r"^([A-Za-z_][A-Za-z0-9_]*=[0-9.]+(,[A-Za-z_][A-Za-z0-9_]*=[0-9.]+)*)?$",
        description="Dask resources an encode item needs, as `dask worker --resources` "
        "spells them (e.g. GPU=1): encode items then run only on workers that declare them")

    @property
    def resources(self) -> dict[str, float]:
        """`worker_resources` as a mapping ({} when empty)."""
        pairs = [p.split("=") for p in self.worker_resources.split(",") if p]
        return {k: float(v) for k, v in pairs}

    not_in_key: ClassVar[frozenset[str]] = frozenset({"device", "worker_resources"})


class CacheConfig(StrictModel):
    """Sharded Zarr cache."""

    shard_views: int = Field(64, ge=1, le=4096)
    latent_dtype: Literal["float16", "float32"] = "float16"


class DagConfig(StrictModel):
    """Execution of the stage graph."""

    executor: Literal["local", "dask"] = "dask"
    workers: int | None = Field(None, ge=1, le=512)
    scheduler: str | None = None
    # extra tries of a failed item; data errors (ValueError, ...) are never retried
    retries: int = Field(2, ge=0, le=20)
    dashboard: bool = False
    # on object storage: the manifest object is rewritten at most this often (seconds) and at
    # the end of every stage; a killed run redoes the items finished since the last write
    manifest_every_s: float = Field(30.0, ge=0, le=3600)


class ClipsConfig(StrictModel):
    """Clip index for training and evaluation."""

    views: int = Field(4, ge=2, le=16)
    gap_min: int = Field(1, ge=1)
    gap_max: int = Field(20, ge=1)
    eval_clips_per_recording: int = Field(300, ge=1)
    eval_fraction: float = Field(0.17, ge=0, le=1)
    hard_baseline_m: float = Field(1.0, gt=0)
    seed: int = Field(0, ge=0)

    @model_validator(mode="after")
    def _gaps(self) -> ClipsConfig:
        if self.gap_max < self.gap_min:
            raise DataError(f"gap_max={self.gap_max} is below gap_min={self.gap_min}")
        return self


class TrainConfig(StrictModel):
    """Lightweight trainer."""

    preset: str = "tiny"
    steps: int = Field(200, ge=1)
    batch_size: int = Field(4, ge=1)
    lr: float = Field(3e-4, gt=0)
    seed: int = Field(0, ge=0)
    bf16: bool = Field(False, description="older spelling of precision: bf16")
    loader_workers: int = Field(0, ge=0)
    device: str = Field("auto", pattern=DEVICE_PATTERN, description="where the model runs "
                        "(train, sample, eval; auto: CUDA when available)")
    precision: Literal["fp32", "bf16", "fp16"] = Field(
        "fp32", description="autocast dtype of the training forward (fp16 with a loss scaler)")
    compile: bool = Field(False, description="torch.compile the backbone")
    grad_accum: int = Field(1, ge=1, description="micro-batches per update: the global batch "
                            "is batch_size x ranks x grad_accum")
    log_every: int = Field(10, ge=1, description="updates between scalar lines of metrics.jsonl")
    eval_every: int = Field(0, ge=0, description="updates between held-out scores (t-binned "
                            "validation loss, model and baseline PSNR); 0: at the end only")


class SampleConfig(StrictModel):
    """Sampler."""

    steps: int = Field(10, ge=1, le=1000)
    guidance: float = Field(1.5, ge=0)
    adaptive_tol: float | None = Field(None, gt=0)


class M3GDConfig(StrictModel):
    """The whole run configuration."""

    version: int = CONFIG_VERSION
    output_dir: Path = Path("out")
    synth: SynthConfig = Field(default_factory=SynthConfig)
    ingest: IngestConfig = Field(default_factory=IngestConfig)
    select: SelectConfig = Field(default_factory=SelectConfig)
    packets: PacketsConfig = Field(default_factory=PacketsConfig)
    encoders: EncodersConfig = Field(default_factory=EncodersConfig)
    cache: CacheConfig = Field(default_factory=CacheConfig)
    dag: DagConfig = Field(default_factory=DagConfig)
    clips: ClipsConfig = Field(default_factory=ClipsConfig)
    train: TrainConfig = Field(default_factory=TrainConfig)
    sample: SampleConfig = Field(default_factory=SampleConfig)

    @property
    def layout(self) -> OutputLayout:
        """Where this run's outputs live under output_dir."""
        return OutputLayout(self.output_dir)

    @model_validator(mode="after")
    def _known_version(self) -> M3GDConfig:
        if self.version != CONFIG_VERSION:
            raise DataError(f"unsupported config version {self.version} (known: {CONFIG_VERSION})")
        return self

    @model_validator(mode="after")
    def _synth_cameras(self) -> M3GDConfig:
        """Synthesized recordings: unless set, ingest the cameras synth writes (no others)."""
        if self.ingest.recordings or "cameras" in self.ingest.model_fields_set:
            return self
        cams = [c for c in self.ingest.cameras if c in self.synth.cameras]
        if cams == list(self.ingest.cameras):
            return self
        return self.model_copy(update={"ingest": self.ingest.model_copy(update={"cameras": cams})})


class ConfigError(DataError):
    """A configuration file that cannot be used; the message is one line."""


def _describe(err: ValidationError, path: Path | None, raw: Any) -> str:
    """One line naming the file, the key and the value of the first error."""
    first = err.errors()[0]
    key = ".".join(str(p) for p in first["loc"]) or "<root>"
    where = str(path) if path is not None else "<config>"
    value = first.get("input")
    if first["type"] == "extra_forbidden":
        return f"{where}: unknown key '{key}' (value {value!r})"
    if first["type"] == "value_error" and isinstance(value, dict):
        # a check across a section's keys: its message names them; the section is noise
        msg = str(first["msg"]).removeprefix("Value error, ")
        return f"{where}: bad value in '{key}': {msg}"
    return f"{where}: bad value for '{key}': {value!r}: {first['msg']}"


def parse_config(raw: Any, path: Path | None = None) -> M3GDConfig:
    """Validate a mapping (from YAML) into a config; raise ConfigError on failure."""
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        where = str(path) if path is not None else "<config>"
        raise ConfigError(f"{where}: top level must be a mapping, got {type(raw).__name__}")
    try:
        return M3GDConfig.model_validate(raw)
    except ValidationError as err:
        raise ConfigError(_describe(err, path, raw)) from err


def load_config(path: Path | None) -> M3GDConfig:
    """Read and validate a YAML config file; None gives the defaults."""
    if path is None:
        return M3GDConfig()
    try:
        raw = yaml.safe_load(Path(path).read_text())
    except FileNotFoundError as err:
        raise ConfigError(f"{path}: config file not found") from err
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}{_yaml_where(err)}: not valid YAML: {_yaml_what(err)}") from err
    return parse_config(raw, Path(path))


def _yaml_where(err: yaml.YAMLError) -> str:
    """':line:column' (1-based) of a YAML error, or '' when the parser gave no position."""
    mark = getattr(err, "problem_mark", None) or getattr(err, "context_mark", None)
    return f":{mark.line + 1}:{mark.column + 1}" if mark is not None else ""


def _yaml_what(err: yaml.YAMLError) -> str:
    """The parser's one-line description of a YAML error."""
    problem = getattr(err, "problem", None)
    context = getattr(err, "context", None)
    if problem:
        return f"{context}, {problem}" if context else str(problem)
    return str(err).splitlines()[0]


def config_to_dict(cfg: BaseModel) -> dict[str, Any]:
    """The effective configuration as plain JSON-compatible data."""
    data: dict[str, Any] = json.loads(cfg.model_dump_json())
    return data


def key_dict(cfg: BaseModel) -> dict[str, Any]:
    """A config section as in `config_to_dict`, without its `not_in_key` fields (cache keys)."""
    drop: frozenset[str] = getattr(cfg, "not_in_key", frozenset())
    return {k: v for k, v in config_to_dict(cfg).items() if k not in drop}


def config_hash(cfg: BaseModel) -> str:
    """SHA-256 of the canonical JSON of a config (or a section of one)."""
    blob = json.dumps(config_to_dict(cfg), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()
