"""Run configuration: the YAML contract, validated by pydantic.

Every section is a strict model (unknown keys are errors). `load_config` turns a
validation failure into one line naming the file, the key and the value.
"""

from __future__ import annotations

import difflib
import hashlib
import json
from pathlib import Path
from typing import Any, ClassVar, Literal

import yaml
from pydantic import BaseModel, Field, ValidationError, model_validator

from schemas.config_base import DEVICE_PATTERN, CameraName, SceneName, SensorVariant, StrictModel
from schemas.config_sections import (
    CameraTopics,
    ChecksConfig,
    HfConfig,
    IngestConfig,
    Lidar,
    LidarTopics,
    SelectConfig,
    TopicsConfig,
)
from schemas.config_synth import SynthConfig
from schemas.errors import DataError
from schemas.layout import OutputLayout
from schemas.modes import PacketMode

CONFIG_VERSION = 1

__all__ = [  # the sections of the data stages: schemas.config_base, _sections, _synth
    "CONFIG_VERSION",
    "DEVICE_PATTERN",
    "CacheConfig",
    "CameraName",
    "CameraTopics",
    "ChecksConfig",
    "ClipsConfig",
    "ConfigError",
    "DagConfig",
    "EncodersConfig",
    "GeometryConfig",
    "HfConfig",
    "IngestConfig",
    "Lidar",
    "LidarTopics",
    "M3GDConfig",
    "PacketsConfig",
    "SampleConfig",
    "SceneName",
    "SelectConfig",
    "SensorVariant",
    "StrictModel",
    "SynthConfig",
    "TopicsConfig",
    "TrainConfig",
    "config_hash",
    "config_to_dict",
    "key_dict",
    "load_config",
    "parse_config",
    "synthetic_refusal",
    "write_config_text",
]

class PacketsConfig(StrictModel):
    """LiDAR packets (eqs. 8-10)."""

    mode: PacketMode = Field("full", description="packet mode of the ablation: full (g and "
                             "h), geom_only (g), zero, learnable or no_lidar")
    min_depth_m: float = Field(0.1, gt=0, le=100, description="points nearer the camera (m) "
                               "are dropped")
    front_surface: bool = Field(False, description="pool only the points within the "
                                "front-surface margin of each cell's nearest point")
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


class GeometryConfig(StrictModel):
    """The geometry verdict after the packets stage (LiDAR edges against image edges)."""

    enabled: bool = Field(True, description="judge every camera's geometry after packets "
                          "(false: no verdict, nothing refused)")
    views: int = Field(24, ge=4, le=256, description="views per camera scored (spread over "
                       "the recording)")
    accept: list[str] = Field(default_factory=list, description="cameras whose `failed` "
                              "verdict the run accepts (exit 0): a camera name, or "
                              "<recording>/<camera>; also `m3gd run --accept-geometry CAMERA`")


class EncodersConfig(StrictModel):
    """Frozen encoders; the defaults are the embedded weight-free ones."""

    image: Literal["patch", "da3"] = Field("patch", description="image encoder: patch "
                                           "(embedded, weight-free) or da3 (Depth Anything 3)")
    image_channels: int = Field(768, ge=1, le=8192, description="latent channels C")
    da3_weights: Path | None = Field(None, description="Depth Anything 3 weights "
                                     "(model.safetensors)")
    allow_random_init: bool = Field(False, description="allow da3 without weights (random "
                                    "init; the cache says pretrained: false)")
    point: Literal["fpfh", "utonia"] = Field("fpfh", description="point encoder: fpfh "
                                             "(embedded, weight-free) or utonia")
    point_channels: int = Field(1224, ge=1, le=8192, description="point feature channels C_u")
    utonia_weights: Path | None = Field(None, description="Utonia weights")
    seed: int = Field(0, ge=0, description="seed of the embedded encoders' fixed projections")
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

    shard_views: int = Field(64, ge=1, le=4096, description="views per shard file")
    latent_dtype: Literal["float16", "float32"] = Field("float16", description="storage dtype "
                                                        "of the latents")


class DagConfig(StrictModel):
    """Execution of the stage graph."""

    executor: Literal["local", "dask"] = Field("dask", description="in-process or a Dask "
                                               "cluster (a LocalCluster unless scheduler)")
    workers: int | None = Field(None, ge=1, le=512, description="LocalCluster workers (null: "
                                "one per core)")
    scheduler: str | None = Field(None, description="address of an existing dask.distributed "
                                  "scheduler (tcp://host:8786)")
    retries: int = Field(2, ge=0, le=20, description="extra tries of a failed item; data "
                         "errors are never retried")
    dashboard: bool = Field(False, description="serve the Dask dashboard and print its link")
    manifest_every_s: float = Field(30.0, ge=0, le=3600, description="on object storage: the "
                                    "manifest is rewritten at most this often (s) and at the "
                                    "end of every stage; a killed run redoes the items "
                                    "finished since the last write")


class ClipsConfig(StrictModel):
    """Clip index for training and evaluation."""

    views: int = Field(4, ge=2, le=16, description="views per clip (sources and targets)")
    gap_min: int = Field(1, ge=1, description="fewest frames between consecutive clip views")
    gap_max: int = Field(20, ge=1, description="most frames between consecutive clip views")
    eval_clips_per_recording: int = Field(300, ge=1, description="clips drawn from each eval "
                                          "recording (split across its cameras)")
    eval_fraction: float = Field(0.17, ge=0, le=1, description="share of the recordings in "
                                 "the eval split (at least one of each with two or more)")
    hard_baseline_m: float = Field(1.0, gt=0, description="a clip whose camera centres lie "
                                   "farther apart (m) is in the hard subset")
    seed: int = Field(0, ge=0, description="seed of the split and the clip draws")
    split: Literal["auto", "recording", "segment"] = Field(
        "auto", description="how clips are split into train and eval: recording (whole "
        "recordings held out), segment (the last eval_fraction of each recording's frames held "
        "out, behind a gap of one clip span, (views - 1) * gap_max frames, that no clip "
        "crosses), auto (recording with two recordings or more, else segment)")

    @model_validator(mode="after")
    def _gaps(self) -> ClipsConfig:
        if self.gap_max < self.gap_min:
            raise DataError(f"gap_max={self.gap_max} is below gap_min={self.gap_min}")
        return self


class TrainConfig(StrictModel):
    """Lightweight trainer; the defaults are the recipe the science bench measured (`m3gd
    bench science`, preset FULL: docs/benchmarks_model.md)."""

    preset: str = Field("tiny", description="network preset (tiny: width 128, depth 4)")
    patch: int | None = Field(1, ge=1, le=8, description="latent cells per token side "
                              "(null: the preset's)")
    steps: int = Field(8000, ge=1, description="optimizer steps")
    batch_size: int = Field(8, ge=1, description="clips per step")
    lr: float = Field(1e-3, gt=0, description="peak AdamW learning rate")
    warmup_steps: int = Field(50, ge=0, description="linear warm-up steps from 0 to lr")
    lr_min: float = Field(1e-5, ge=0, description="learning rate at the end of the cosine "
                          "decay (over steps - warmup_steps)")
    ema_decay: float = Field(0.998, ge=0, lt=1, description="decay of the EMA weights")
    seed: int = Field(0, ge=0, description="seed of the weights, the clip order and the noise")
    bf16: bool = Field(False, description="older spelling of precision: bf16")
    loader_workers: int = Field(0, ge=0, description="DataLoader worker processes")
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

    steps: int = Field(10, ge=1, le=1000, description="Euler steps K")
    guidance: float = Field(1.0, ge=0, description="classifier-free guidance scale s (1: "
                            "none; the science bench's setting)")
    adaptive_tol: float | None = Field(None, gt=0, description="stop early when the t=0 "
                                       "extrapolation changes by less than this (relative)")
    temperature: float = Field(1.0, ge=0, allow_inf_nan=False, description="scale of the "
                               "start noise (1: the paper's sampler, a draw; below 1 trades "
                               "diversity for accuracy; 0: deterministic)")


class M3GDConfig(StrictModel):
    """The whole run configuration."""

    version: int = Field(CONFIG_VERSION, description="configuration format version")
    output_dir: Path = Field(Path("out"), description="where every output goes: a folder or "
                             "s3://bucket/prefix")
    synthetic: bool = Field(False, description="when ingest.recordings names none, synthesize "
                            "the missions of synth.scenes and run on them (the embedded "
                            "defaults and `m3gd demo` set it; a configuration file asks for it "
                            "here, never by leaving recordings out)")
    synth: SynthConfig = Field(default_factory=SynthConfig)
    ingest: IngestConfig = Field(default_factory=IngestConfig)
    select: SelectConfig = Field(default_factory=SelectConfig)
    packets: PacketsConfig = Field(default_factory=PacketsConfig)
    geometry: GeometryConfig = Field(default_factory=GeometryConfig)
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
    def _select_lidar(self) -> M3GDConfig:
        self.select.lidar_of(self.ingest.topics)  # DataError naming an unknown LiDAR
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


def _section_at(loc: tuple[Any, ...]) -> type[BaseModel] | None:
    """The config model holding the key at `loc` (None past a list or a plain value)."""
    model: type[BaseModel] = M3GDConfig
    for part in loc[:-1]:
        field = model.model_fields.get(str(part))
        sub = field.annotation if field is not None else None
        if not (isinstance(sub, type) and issubclass(sub, BaseModel)):
            return None
        model = sub
    return model


def _did_you_mean(loc: tuple[Any, ...]) -> str:
    """' (did you mean 'a.b'?)' for an unknown key close to a known one of its section."""
    model = _section_at(loc)
    if model is None:
        return ""
    close = difflib.get_close_matches(str(loc[-1]), list(model.model_fields), n=1, cutoff=0.6)
    if not close:
        return ""
    return f" (did you mean '{'.'.join(str(p) for p in (*loc[:-1], close[0]))}'?)"


def _one_error(error: Any) -> str:
    """One error of a validation: the key, the value and what is wrong with it."""
    key = ".".join(str(p) for p in error["loc"]) or "<root>"
    value = error.get("input")
    if error["type"] == "extra_forbidden":
        return f"unknown key '{key}' (value {value!r}){_did_you_mean(tuple(error['loc']))}"
    if error["type"] == "value_error" and isinstance(value, dict):
        # a check across a section's keys: its message names them; the section is noise
        msg = str(error["msg"]).removeprefix("Value error, ")
        return f"bad value in '{key}': {msg}"
    return f"bad value for '{key}': {value!r}: {error['msg']}"


def _describe(err: ValidationError, path: Path | None, raw: Any) -> str:
    """One line naming the file, then every bad key with its value (`; ` between them)."""
    where = str(path) if path is not None else "<config>"
    return f"{where}: " + "; ".join(_one_error(e) for e in err.errors())


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
    """Read and validate a YAML config file; None gives the embedded defaults (the demo:
    `synthetic` on). A file that is empty or holds only comments is refused (a configuration
    cut by a killed write or a full disk must not run as the defaults)."""
    if path is None:
        return M3GDConfig(synthetic=True)
    try:
        raw = yaml.safe_load(Path(path).read_text())
    except FileNotFoundError as err:
        raise ConfigError(f"{path}: config file not found") from err
    except IsADirectoryError as err:
        raise ConfigError(f"{path}: a folder, not a config file") from err
    except UnicodeDecodeError as err:
        raise ConfigError(f"{path}: not a text file ({err.reason})") from err
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}{_yaml_where(err)}: not valid YAML: {_yaml_what(err)}") from err
    if raw is None:
        raise ConfigError(f"{path}: an empty configuration (no key, only comments or nothing); "
                          "write at least one key, e.g. output_dir")
    return parse_config(raw, Path(path))


def synthetic_refusal(cfg: M3GDConfig) -> str | None:
    """Why a run of `cfg` is refused: no recording named and synthesis not asked for (it
    would synthesize by omission); None when it may run."""
    if cfg.ingest.recordings or not cfg.synth.scenes or cfg.synthetic:
        return None
    return ("no recording to run on: name them in ingest.recordings (or as arguments), or set "
            "`synthetic: true` to synthesize the missions of synth.scenes (`m3gd demo` does)")


def write_config_text(path: Path, text: str) -> Path:
    """Write a configuration file whole or not at all: `text` into a temporary beside the
    file, flushed to disk (fsync), renamed over it, the folder synced. A kill or a full disk
    leaves the previous file (or none) and at most a hidden `.<name>.<pid>.tmp`, which the
    next write removes. A symbolic link is written through: the file it points to is
    replaced and the link kept. Returns the path written."""
    import os

    target = Path(os.path.realpath(path)) if path.is_symlink() else path
    target.parent.mkdir(parents=True, exist_ok=True)
    for stale in target.parent.glob(f".{target.name}.*.tmp"):  # left by a killed writer
        stale.unlink(missing_ok=True)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise
    _sync_folder(target.parent)
    return target


def _sync_folder(folder: Path) -> None:
    """fsync a folder (the rename in it reaches the disk); a no-op where folders cannot be
    opened (Windows)."""
    import os

    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


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
