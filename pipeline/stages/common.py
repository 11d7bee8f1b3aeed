"""Paths, cache keys and per-process resources shared by the stages."""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from schemas.cache_io import node_attrs
from schemas.cache_layout import GroupAttrs
from schemas.config import EncodersConfig, M3GDConfig, key_dict
from schemas.errors import DataError
from schemas.manifest import InputIdentity


def recordings(cfg: M3GDConfig) -> list[Path]:
    """Mission folders of this run: configured ones, or the synthesized ones."""
    if cfg.ingest.recordings:
        return [Path(p) for p in cfg.ingest.recordings]
    base = cfg.layout.recordings
    return [base / synth_mission_name(scene, cfg.synth.seed) for scene in cfg.synth.scenes]


def synth_mission_name(scene: str, seed: int) -> str:
    """Name of a synthesized mission folder."""
    return f"synth_{scene}_s{seed}"


def synth_scene_of(cfg: M3GDConfig, mission: str) -> str:
    """The configured scene whose synthesized mission is named `mission`."""
    for scene in cfg.synth.scenes:
        if synth_mission_name(scene, cfg.synth.seed) == mission:
            return scene
    raise DataError(f"{mission}: not the mission of any scene in synth.scenes {cfg.synth.scenes}")


def recording_names(cfg: M3GDConfig) -> list[str]:
    """Recording names (mission folder names) in a stable order."""
    return [p.name for p in recordings(cfg)]


def mission_of(cfg: M3GDConfig, recording: str) -> Path:
    """Mission folder of a recording name."""
    for path in recordings(cfg):
        if path.name == recording:
            return path
    raise KeyError(f"recording {recording!r} is not part of this run")


def input_identity(mission: Path) -> list[dict[str, Any]]:
    """Identity (path, size, mtime) of every bag of a mission folder (Hugging Face layout: of
    every Zarr metadata file and every image folder, whose mtime changes with its files)."""
    bags = sorted(mission.glob("*.bag")) + sorted(mission.glob("*.mcap"))
    if (mission / "data").is_dir():
        bags += sorted(p for p in (mission / "data").rglob("*")
                       if p.name in (".zarray", ".zattrs", "zarr.json"))
        bags += sorted(p for p in mission.glob("images/*") if p.is_dir())
    return [InputIdentity.of(b).__dict__ for b in bags]


def cache_key(*parts: Any) -> str:
    """SHA-256 of the canonical JSON of config sections and other identities."""
    norm = [key_dict(p) if isinstance(p, BaseModel) else p for p in parts]
    blob = json.dumps(norm, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()[:32]


@functools.lru_cache(maxsize=4)
def image_encoder(cfg: EncodersConfig) -> Any:
    """The configured image encoder, built once per process (the config is hashable)."""
    from model.encoders.registry import image_encoder_from_config

    return image_encoder_from_config(cfg)


@functools.lru_cache(maxsize=4)
def point_encoder(cfg: EncodersConfig) -> Any:
    """The configured point encoder, built once per process."""
    from model.encoders.registry import point_encoder_from_config

    return point_encoder_from_config(cfg)


def index_path(cfg: M3GDConfig, recording: str) -> Path:
    """Index folder of one recording."""
    return cfg.layout.index_of(recording)


def run_groups(cfg: M3GDConfig) -> list[tuple[str, str, GroupAttrs]]:
    """(recording, camera, attrs) of every cache group of this run's recordings."""
    cache = cfg.layout.cache
    out = []
    for rec in recording_names(cfg):
        for cam in cfg.ingest.cameras:
            where = cache / rec / cam
            if (where / "zarr.json").exists():
                out.append((rec, cam, GroupAttrs.from_attrs(node_attrs(where), str(where))))
    return out
