"""Packets stage: the point encoder once per selected sweep, packets g and h per view.

One item per recording. Shard rows (shard k of every camera) are processed in
order; each selected sweep is decoded and encoded once, and its per-point
features are shared by every view (any camera) that selected it, through a small
LRU of recent sweeps (views of neighbouring shards select neighbouring sweeps).
Sweeps that no view selects are never decoded. Per-shard statistics rows are
written next to the packets; a shard row whose done-marks match is skipped.
"""

from __future__ import annotations

import dataclasses
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import zarr

from packets.assemble import SweepFeatures, packet_from_support, view_support
from pipeline.cache.store import (
    ensure_array,
    mark_shard_done,
    open_root,
    shard_done,
    shard_slice,
    write_region,
)
from pipeline.run.stage import Item, ItemResult
from pipeline.stages.common import (
    cache_key,
    index_path,
    mission_of,
    point_encoder,
    recording_names,
)
from pipeline.stages.encode import F16_MAX
from pipeline.stats.rows import ShardStats
from schemas.cache_layout import GridSpec, GroupAttrs, packet_arrays, shard_regions
from schemas.config import M3GDConfig
from schemas.recording_index import SELECTION, SELECTION_FILE, SWEEPS, read_index_table

LRU_SWEEPS = 6


def plan_packets(cfg: M3GDConfig) -> list[Item]:
    """One item per recording."""
    return [Item(rec, cache_key("packets", cfg.packets, cfg.encoders, cfg.ingest, cfg.select,
                                cfg.cache, rec)) for rec in recording_names(cfg)]


@dataclass
class SweepCache:
    """Decoded sweeps and their features, least recently used evicted first."""

    loader: Any
    encoder: Any | None
    entries: OrderedDict[int, tuple[np.ndarray, SweepFeatures | None]] = field(
        default_factory=OrderedDict)
    decoded: int = 0

    def get(self, sweep: int) -> tuple[np.ndarray, SweepFeatures | None]:
        """xyz (N, 3) float32 and features (N, C_u) of a sweep, computed at most once."""
        if sweep in self.entries:
            self.entries.move_to_end(sweep)
            return self.entries[sweep]
        xyz, intensity = self.loader(sweep)
        self.decoded += 1
        feat = None
        if self.encoder is not None:
            feat = SweepFeatures.from_array(self.encoder.encode(xyz, intensity))
        self.entries[sweep] = (xyz, feat)
        if len(self.entries) > LRU_SWEEPS:
            self.entries.popitem(last=False)
        return self.entries[sweep]


def _sweep_loader(cfg: M3GDConfig, recording: str) -> Any:
    """A function sweep index -> (xyz (N,3) float32, intensity (N,) float32)."""
    from pipeline.ingest.pointcloud import load_sweep

    mission = mission_of(cfg, recording)
    table = read_index_table(index_path(cfg, recording) / "sweeps.parquet", SWEEPS)
    rows = {r["sweep"]: r for r in table.to_pylist()}

    def load(sweep: int) -> tuple[np.ndarray, np.ndarray]:
        sw = load_sweep(mission, rows[sweep])
        return sw.xyz, sw.intensity

    return load


def run_packets(cfg: M3GDConfig, item: Item) -> ItemResult:
    """Build and store the packets of every valid view of one recording."""
    rec = item.key
    root = open_root(cfg.output_dir / "cache.zarr")
    sel = read_index_table(index_path(cfg, rec) / SELECTION_FILE, SELECTION)
    groups = {c: root[f"{rec}/{c}"] for c in cfg.ingest.cameras if f"{rec}/{c}" in root}
    attrs = {c: GroupAttrs.from_attrs(dict(g.attrs), f"{rec}/{c}") for c, g in groups.items()}
    with_h = cfg.packets.mode == "full"
    enc = point_encoder(cfg.encoders) if with_h else None
    sweeps = SweepCache(_sweep_loader(cfg, rec), enc)
    n_rows = max((len(shard_regions(a.n_views, a.shard_views)) for a in attrs.values()), default=0)
    done = skipped = 0
    for k in range(n_rows):
        todo = [c for c in groups if k < len(shard_regions(attrs[c].n_views, attrs[c].shard_views))
                and not shard_done(groups[c], "packets", k, item.cache_key)]
        skipped += len(groups) - len(todo)
        for cam in todo:
            done += _packet_shard(cfg, rec, cam, k, groups[cam], attrs[cam], sel, sweeps,
                                  with_h, item.cache_key)
    _record_identity(groups, enc, cfg.packets.mode if with_h else "geom_only")
    return ItemResult(done=done, detail={"sweeps_decoded": sweeps.decoded,
                                         "shards_skipped": skipped})


def _packet_shard(cfg: M3GDConfig, rec: str, cam: str, shard: int, group: Any,
                  attrs: GroupAttrs, sel: pa.Table, sweeps: SweepCache, with_h: bool,
                  key: str) -> int:
    """Packets of one camera shard: write g (and h), the stats part, then the done-mark."""
    region = shard_slice(shard, attrs.n_views, attrs.shard_views)
    rows = {r["frame"]: r for r in sel.filter(pc.equal(sel["camera"], cam)).to_pylist()
            if region.start <= r["frame"] < region.stop}
    grid = GridSpec(attrs.image_h, attrs.image_w, attrs.patch)
    specs = packet_arrays(grid, cfg.encoders.point_channels, with_h)
    out = {s.name: np.zeros((region.stop - region.start, *s.view_shape), np.float32)
           for s in specs}
    stats = ShardStats(rec, cam)
    built = 0
    for frame in range(region.start, region.stop):
        row = rows.get(frame)
        if row is None or row["status"] != "ok":
            stats.add_view(frame, row["stamp_ns"] if row else 0, None,
                           row["dtau_s"] if row else None, None,
                           row["reason"] if row else "not_selected")
            continue
        xyz, feat = sweeps.get(row["sweep"])
        sup = view_support(xyz, np.reshape(row["K_out"], (3, 3)),
                           np.reshape(row["T_cam_lidar"], (4, 4)), (grid.image_h, grid.image_w),
                           min_depth_m=cfg.packets.min_depth_m, patch=grid.patch)
        margin = cfg.packets.front_margin_m if cfg.packets.front_surface else None
        pkt = packet_from_support(sup, row["dtau_s"], feat, mode="full" if with_h else "geom_only",
                                  front_margin_m=margin)
        out["g"][frame - region.start] = pkt.g
        if with_h and pkt.h is not None:
            out["h"][frame - region.start] = np.clip(pkt.h, -F16_MAX, F16_MAX)
        stats.add_view(frame, row["stamp_ns"], row["sweep_stamp_ns"], row["dtau_s"], sup, None)
        built += 1
    for spec in specs:
        arr = ensure_array(group, spec, attrs.n_views, attrs.shard_views)
        write_region(arr, region.start, out[spec.name].astype(spec.dtype))
    stats.write(cfg.output_dir, shard)
    mark_shard_done(group, "packets", shard, key)
    return built


def _record_identity(groups: dict[str, Any], enc: Any | None, mode: str) -> None:
    """Store the point encoder identity and the packet mode in every group's attributes."""
    ident = enc.identity() if enc is not None else None
    for cam, group in groups.items():
        assert isinstance(group, zarr.Group)
        fresh = GroupAttrs.from_attrs(dict(group.attrs), cam)
        group.attrs.update(dataclasses.replace(fresh, point_encoder=ident,
                                               packet_mode=mode).to_attrs())
