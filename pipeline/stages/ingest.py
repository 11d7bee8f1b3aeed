"""Synth, ingest and select stages: recordings to index tables and cached images and cameras."""

from __future__ import annotations

import logging

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import zarr

from pipeline.cache.store import ensure_array, open_root, write_region
from pipeline.ingest.staging import mission_identity, staged
from pipeline.run.reads import RECORDING_GROUPS, Reads, StoreReads
from pipeline.run.stage import Item, ItemKey, ItemResult
from pipeline.stages.common import (
    cache_key,
    index_path,
    input_identity,
    mission_of,
    recording_names,
    synth_mission_name,
    synth_scene_of,
)
from pipeline.stages.images import ImageCacheSink
from schemas.cache_layout import GridSpec, GroupAttrs, view_meta_arrays
from schemas.config import M3GDConfig
from schemas.errors import DataError
from schemas.object_store import is_url
from schemas.recording_index import SELECTION, SELECTION_FILE, ViewStatus, read_index_table

log = logging.getLogger(__name__)

SYNTH_READS = StoreReads(Reads(()))
"""A synth item reads nothing from the output."""
INGEST_READS = StoreReads(Reads(RECORDING_GROUPS, ("stamp_ns", "K")))
"""Its recording's group and index; rewritten arrays (images are written as whole shards)."""
SELECT_READS = StoreReads(Reads(RECORDING_GROUPS, tuple(s.name for s in view_meta_arrays())))
"""Its recording's group and index; the view metadata arrays it rewrites."""


def plan_synth(cfg: M3GDConfig) -> list[Item]:
    """One item per scene, only when no real recording is configured."""
    if cfg.ingest.recordings:
        return []
    return [Item(ItemKey(synth_mission_name(s, cfg.synth.seed)), cache_key("synth", cfg.synth, s))
            for s in cfg.synth.scenes]


def run_synth(cfg: M3GDConfig, item: Item) -> ItemResult:
    """Generate one synthetic recording."""
    from pipeline.synth.api import synthesize

    mission = item.key.require_recording()
    result = synthesize(cfg.layout.recordings, cfg.synth, synth_scene_of(cfg, mission),
                        mission=mission)
    return ItemResult(done=1, detail={"result": str(result)})


def plan_ingest(cfg: M3GDConfig) -> list[Item]:
    """One item per recording, keyed by its bags' identities and the ingest config."""
    items = []
    for rec in recording_names(cfg):
        mission = mission_of(cfg, rec)
        ident = (mission_identity(mission) if is_url(mission)
                 else input_identity(mission) if mission.exists() else [])
        items.append(Item(ItemKey(rec), cache_key("ingest", cfg.ingest, cfg.cache, ident)))
    return items


def run_ingest(cfg: M3GDConfig, item: Item) -> ItemResult:
    """Index one recording and write its rectified images into the cache."""
    from pipeline.ingest.recording import ingest_recording

    grid = GridSpec(cfg.ingest.out_height, cfg.ingest.out_width)
    rec = item.key.require_recording()
    sink = ImageCacheSink(cfg.output_dir, rec, grid, cfg.cache.shard_views)
    with staged(mission_of(cfg, rec)) as mission:  # s3:// missions: a scratch copy
        result = ingest_recording(mission, cfg.output_dir, cfg.ingest, sink)
    counts = sink.close()
    log.info("ingest %s: input format %s", item.key, result.input_format)
    return ItemResult(done=sum(counts.values()), rejected=sum(result.rejects.values()),
                      detail={"images": counts, "rejects": result.rejects,
                              "sweeps": result.sweeps, "format": result.input_format,
                              "checks": result.checks},
                      warnings=result.warnings)


def plan_select(cfg: M3GDConfig) -> list[Item]:
    """One item per recording."""
    return [Item(ItemKey(rec), cache_key("select", cfg.ingest, cfg.select, cfg.cache, rec))
            for rec in recording_names(cfg)]


def run_select(cfg: M3GDConfig, item: Item) -> ItemResult:
    """Select the nearest sweep of every view and store the per-view cameras in the cache."""
    from pipeline.select import select_views

    rec = item.key.require_recording()
    result = select_views(index_path(cfg, rec), cfg.select, cfg.ingest)
    table = read_index_table(index_path(cfg, rec) / SELECTION_FILE, SELECTION)
    root = open_root(cfg.layout.cache)
    ok = 0
    for cam in cfg.ingest.cameras:
        if f"{rec}/{cam}" in root:
            ok += write_view_meta(root[f"{rec}/{cam}"], table, cam)
    return ItemResult(done=ok, rejected=table.num_rows - ok, detail={"select": str(result)})


def write_view_meta(group: zarr.Group | zarr.Array, table: pa.Table, camera: str) -> int:
    """Write one camera's selection columns into its cache group; return valid views."""
    assert isinstance(group, zarr.Group)
    attrs = GroupAttrs.from_attrs(dict(group.attrs), str(group.path))
    rows = table.filter(pc.equal(table["camera"], camera)).sort_by("frame")
    n = attrs.n_views
    frames = rows["frame"].to_numpy()
    if frames.size and (frames.max() >= n or frames.min() < 0):
        raise DataError(f"{group.path}: selection frames exceed the {n} cached views")
    cols = {
        "sweep_stamp_ns": ("sweep_stamp_ns", np.int64, ()),
        "dtau_s": ("dtau_s", np.float64, ()),
        "T_world_cam": ("T_world_cam", np.float64, (4, 4)),
        "T_cam_lidar": ("T_cam_lidar", np.float64, (4, 4)),
    }
    data = {}
    for name, (col, dtype, shape) in cols.items():
        full = np.zeros((n, *shape), dtype)
        values = np.asarray(rows[col].to_pylist(), dtype).reshape(-1, *shape)
        full[frames] = values
        data[name] = full
    valid = np.zeros(n, bool)
    valid[frames] = np.asarray(rows["status"].to_pylist()) == ViewStatus.OK
    data["valid"] = valid
    for spec in view_meta_arrays():
        arr = ensure_array(group, spec, n, attrs.shard_views)
        write_region(arr, 0, data[spec.name])
    return int(valid.sum())
