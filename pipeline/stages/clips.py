"""Clips stage: the train / eval clip index with a recording-level split."""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa
import zarr

from model.clips import sample_clips, split_recordings
from pipeline.cache.store import camera_groups, open_root, stage_marked
from pipeline.run.keys import ItemKey
from pipeline.run.reads import Reads, StoreReads
from pipeline.run.stage import Item, ItemResult
from pipeline.stages.common import cache_key, upstream_key
from schemas.cache_io import read_views
from schemas.cache_layout import PACKETS, GroupAttrs, shard_regions
from schemas.config import M3GDConfig
from schemas.layout import CACHE_DIRNAME, DONE_DIRNAME
from schemas.missions import recording_names
from schemas.tables import CLIPS, write_table

CLIPS_ITEM = ItemKey.cross("clips")

CLIPS_READS = StoreReads(Reads((CACHE_DIRNAME, DONE_DIRNAME), ("valid", "T_world_cam")))
"""The cache metadata and done-marks, and the valid flags and poses the clips are drawn from."""


def plan_clips(cfg: M3GDConfig) -> list[Item]:
    """A single item: the clip index of the whole run."""
    return [Item(CLIPS_ITEM, cache_key(upstream_key(cfg), cfg.clips, recording_names(cfg)))]


def _camera_clips(group: zarr.Group, split: str, count: int, cfg: M3GDConfig,
                  seed: int) -> list[dict[str, object]]:
    """Clip rows of one recording-camera group."""
    attrs = GroupAttrs.from_attrs(dict(group.attrs), str(group.path))
    path = cfg.layout.cache / group.path
    frames = list(range(attrs.n_views))
    if not frames:
        return []
    valid = np.flatnonzero(read_views(path / "valid", frames)).astype(np.int64)
    centres = read_views(path / "T_world_cam", frames)[:, :3, 3]
    c = cfg.clips
    clips = sample_clips(valid, centres, count, split, c.views, c.gap_min, c.gap_max, seed)
    return [{"split": split, "recording": attrs.recording, "camera": attrs.camera,
             "frames": list(k.frames), "is_target": list(k.is_target),
             "max_baseline_m": k.max_baseline_m,
             "hard": k.max_baseline_m > c.hard_baseline_m} for k in clips]


def run_clips(cfg: M3GDConfig, item: Item) -> ItemResult:
    """Split recordings, sample train and eval clips, write `clips.parquet`."""
    names = recording_names(cfg)
    split = split_recordings(names, cfg.clips.eval_fraction, cfg.clips.seed)
    root = open_root(cfg.layout.cache)
    rows: list[dict[str, object]] = []
    warnings: list[str] = []
    for r_i, rec in enumerate(names):
        groups = camera_groups(root, rec, cfg.ingest.cameras)
        attrs = {c: GroupAttrs.from_attrs(dict(g.attrs), str(g.path)) for c, g in groups.items()}
        unpacked = [c for c in groups if not _packets_complete(groups[c], attrs[c])]
        warnings += [f"{rec}/{c}: packets incomplete; left out of the clip index until a rerun "
                     "completes them" for c in unpacked]
        cams = [c for c in groups if c not in unpacked]
        for c_i, cam in enumerate(cams):
            group = groups[cam]
            assert isinstance(group, zarr.Group)
            n_views = attrs[cam].n_views
            per_rec = cfg.clips.eval_clips_per_recording  # split exactly across cameras
            share = per_rec // len(cams) + (1 if c_i < per_rec % len(cams) else 0)
            count = share if split[rec] == "eval" else n_views
            seed = cfg.clips.seed * 1000 + r_i * 10 + c_i
            rows.extend(_camera_clips(group, split[rec], count, cfg, seed))
    for i, row in enumerate(rows):
        row["clip_id"] = i
    write_table(pa.Table.from_pylist(rows, schema=CLIPS), CLIPS, cfg.layout.clips)
    n_eval = sum(r["split"] == "eval" for r in rows)
    return ItemResult(done=len(rows), detail={"train": len(rows) - n_eval, "eval": n_eval,
                                              "split": split}, warnings=warnings)


def _packets_complete(group: Any, attrs: GroupAttrs) -> bool:
    """Whether the packets stage marked every shard of a recording-camera group done."""
    return stage_marked(group, PACKETS, len(shard_regions(attrs.n_views, attrs.shard_views)))
