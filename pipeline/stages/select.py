"""Select stage: the nearest sweep of every view, signed Δτ, and the per-view cameras (cache)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import zarr

from pipeline.run.keys import ItemKey
from pipeline.run.reads import RECORDING_GROUPS, Reads, StoreReads
from pipeline.run.stage import Item, ItemResult
from pipeline.stages.common import cache_key, index_path
from schemas.cache_layout import SELECT, GroupAttrs, group_name, view_meta_arrays
from schemas.config import M3GDConfig
from schemas.errors import DataError
from schemas.missions import recording_names
from schemas.recording_index import (
    SELECTION,
    SELECTION_FILE,
    SELECTION_LIDARS_FILE,
    ViewStatus,
    read_index_table,
)
from store.cache_store import ensure_array, open_root, write_region

SELECT_READS = StoreReads(Reads(RECORDING_GROUPS, tuple(s.name for s in view_meta_arrays())))
"""Its recording's group and index; the view metadata arrays it rewrites."""


def select_outputs(cfg: M3GDConfig, item: Item) -> list[Path]:
    """The selection table(s) a finished select item wrote (with `selection_lidars` when the
    packets merge several LiDARs)."""
    folder = index_path(cfg, item.key.require_recording())
    return [folder / SELECTION_FILE] + ([folder / SELECTION_LIDARS_FILE]
                                        if cfg.select.merges() else [])


def plan_select(cfg: M3GDConfig) -> list[Item]:
    """One item per recording."""
    return [Item(ItemKey(rec), cache_key(SELECT, cfg.ingest, cfg.select, cfg.cache, rec))
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
        if group_name(rec, cam) in root:
            ok += write_view_meta(root[group_name(rec, cam)], table, cam)
    return ItemResult(done=ok, rejected=table.num_rows - ok, detail={SELECT: str(result)})


def write_view_meta(group: zarr.Group | zarr.Array[Any], table: pa.Table, camera: str) -> int:
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
    for spec in view_meta_arrays():  # rewritten whole: a damaged chunk is never read back
        if spec.name in group:
            del group[spec.name]
        arr = ensure_array(group, spec, n, attrs.shard_views)
        write_region(arr, 0, data[spec.name])
    return int(valid.sum())
