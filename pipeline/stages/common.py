"""Paths, cache keys and per-process resources shared by the stages."""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from pipeline.ingest.sources.base import list_names
from pipeline.ingest.sources.registry import claiming
from schemas.cache_layout import GroupAttrs
from schemas.config import EncodersConfig, M3GDConfig, key_dict
from schemas.manifest import InputIdentity
from schemas.missions import recording_names
from store.cache_io import node_attrs


def input_identity(mission: Path) -> list[dict[str, Any]]:
    """Identity (path, size, mtime) of the files a mission folder's source names as its
    identity (`RecordingSource.identity`: bags; Hugging Face layout: every Zarr metadata file
    and every image folder, whose mtime changes with its files)."""
    names = list_names(mission)
    return [InputIdentity.of(mission / n).__dict__ for n in claiming(names).identity(names)]


def cache_key(*parts: Any) -> str:
    """SHA-256 of the canonical JSON of config sections and other identities."""
    norm = [key_dict(p) if isinstance(p, BaseModel) else p for p in parts]
    blob = json.dumps(norm, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()[:32]


def upstream_key(cfg: M3GDConfig) -> str:
    """Cache key part shared by the stats and clips stages (everything upstream of them)."""
    return cache_key(cfg.ingest, cfg.select, cfg.encoders, cfg.packets, cfg.cache)


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
