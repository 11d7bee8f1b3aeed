"""Packets stage: the point encoder once per selected sweep, packets g and h per view.

One item per recording, per shard row, or chosen from the worker count and recording sizes
(`packets.items`, default auto: `pipeline.stages.packets_plan`). Shard rows (shard k of
every camera) are processed in order; each selected sweep is decoded and encoded once
per item, and its per-point features are shared by every view (any camera) that selected
it, through a small LRU of recent sweeps (views of neighbouring shards select neighbouring sweeps).
Sweeps that no view selects are never decoded. Per-shard statistics rows are
written next to the packets; a shard row whose done-marks match is skipped.
"""

from __future__ import annotations

import dataclasses
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import zarr

from packets.assemble import SweepFeatures, packet_from_support, view_support
from packets.merge import SweepPart, merge_in_camera
from pipeline.run.keys import ItemKey
from pipeline.run.reads import RECORDING_GROUPS, Reads, StoreReads
from pipeline.run.stage import Item, ItemResult
from pipeline.stages.common import cache_key, index_path, point_encoder, run_groups
from pipeline.stages.packets_plan import choose_units, planned_workers, recording_costs
from pipeline.stats.rows import ShardStats
from schemas.cache_layout import (
    F16_MAX,
    H_CELLS,
    PACKETS,
    GridSpec,
    GroupAttrs,
    group_name,
    packet_arrays,
    shard_regions,
)
from schemas.config import M3GDConfig
from schemas.layout import CACHE_DIRNAME, DONE_DIRNAME, INDEX_DIRNAME
from schemas.missions import mission_of, recording_names
from schemas.modes import packet_mode
from schemas.packed_cells import occupied_cells, pack_rows
from schemas.recording_index import (
    SELECTION,
    SELECTION_FILE,
    SELECTION_LIDARS,
    SELECTION_LIDARS_FILE,
    SWEEPS,
    read_index_table,
)
from store.cache_store import (
    camera_groups,
    drop_array,
    ensure_array,
    mark_shard_done,
    open_root,
    set_group_attrs,
    shard_done,
    shard_slice,
    write_packed,
    write_region,
)
from store.shard_writer import ShardWriter

LRU_SWEEPS = 6

PACKETS_READS = StoreReads(Reads((*RECORDING_GROUPS, f"{DONE_DIRNAME}/{{r}}"), ("g",)),
                           plan=(CACHE_DIRNAME, INDEX_DIRNAME))
"""Its recording's group, index and done-marks; `g` chunks, which it rewrites (h_cells are
written whole); the plan reads the cache metadata and the indexes."""


def plan_packets(cfg: M3GDConfig) -> list[Item]:
    """One item per recording, per shard row, or chosen (`packets.items`: recording,
    shard_row, auto; see `packets_plan`): key `<rec>` or `<rec>/<k>`.

    Shard row k holds shard k of every camera of the recording. The cache key does not
    depend on the split: outputs are identical either way.
    """
    items_mode = cfg.packets.items
    attrs: dict[str, list[GroupAttrs]] = {}
    for rec, _, a in run_groups(cfg) if items_mode != "recording" else []:  # metadata once
        attrs.setdefault(rec, []).append(a)
    keys = {rec: cache_key(PACKETS, cfg.packets.model_copy(update={"items": "recording"}),
                           cfg.encoders, cfg.ingest, cfg.select, cfg.cache, rec)
            for rec in recording_names(cfg)}
    if items_mode == "recording":
        return [Item(ItemKey(rec), key) for rec, key in keys.items()]
    if items_mode == "shard_row":
        return [Item(ItemKey(rec, shard=k), key) for rec, key in keys.items()
                for k in range(_n_rows(attrs.get(rec, [])))]
    whole: dict[str, float] = {}
    rows: dict[str, list[float]] = {}
    for rec in keys:
        try:
            whole[rec], rows[rec] = recording_costs(index_path(cfg, rec), attrs.get(rec, []),
                                                   cfg.select.merges())
        except FileNotFoundError:  # no selection yet (stage not run): one item, unsplit
            whole[rec], rows[rec] = 0.0, []
    return [Item(ItemKey(u.recording, shard=u.row), keys[u.recording])
            for u in choose_units(whole, rows, planned_workers(cfg))]


def _n_rows(groups: Iterable[GroupAttrs]) -> int:
    """Shard rows of a recording: the most shards any of its camera groups has (0 if none)."""
    return max((len(shard_regions(a.n_views, a.shard_views)) for a in groups), default=0)


@dataclass
class SweepCache:
    """Decoded sweeps and their features, least recently used evicted first."""

    loader: Any
    encoder: Any | None
    capacity: int = LRU_SWEEPS
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
        if len(self.entries) > self.capacity:
            self.entries.popitem(last=False)
        return self.entries[sweep]


def _sweep_loader(cfg: M3GDConfig, recording: str, mission: Path) -> Any:
    """A function sweep index -> (xyz (N,3) float32, intensity (N,) float32), reading the
    bags of the (local or staged) mission folder `mission`."""
    from pipeline.ingest.sources.sweep_reader import load_sweep

    table = read_index_table(index_path(cfg, recording) / "sweeps.parquet", SWEEPS)
    rows = {r["sweep"]: r for r in table.to_pylist()}

    def load(sweep: int) -> tuple[np.ndarray, np.ndarray]:
        sw = load_sweep(mission, rows[sweep])
        return sw.xyz, sw.intensity

    return load


def run_packets(cfg: M3GDConfig, item: Item) -> ItemResult:
    """Build and store the packets of every valid view of one recording (or shard row); a
    mission on `s3://` is staged to scratch for the item (pipeline.ingest.sources.staging)."""
    from pipeline.ingest.sources.staging import staged

    with staged(mission_of(cfg, item.key.require_recording())) as mission:
        return _run_packets(cfg, item, mission)


def _run_packets(cfg: M3GDConfig, item: Item, mission: Path) -> ItemResult:
    """Body of run_packets, the mission's bags read from the folder `mission`."""
    rec, row = item.key.require_recording(), item.key.shard
    root = open_root(cfg.layout.cache)
    sel = Selection.read(index_path(cfg, rec), cfg.select.merges())
    groups = camera_groups(root, rec, cfg.ingest.cameras)
    attrs = {c: GroupAttrs.from_attrs(dict(g.attrs), group_name(rec, c)) for c, g in groups.items()}
    with_h = packet_mode(cfg.packets.mode).reads_h
    enc = point_encoder(cfg.encoders) if with_h else None
    sweeps = SweepCache(_sweep_loader(cfg, rec, mission), enc,
                        capacity=LRU_SWEEPS * len(cfg.select.lidars_of(cfg.ingest.topics)))
    done = skipped = 0
    for k in ([row] if row is not None else range(_n_rows(attrs.values()))):
        todo = [c for c in groups if k < len(shard_regions(attrs[c].n_views, attrs[c].shard_views))
                and not shard_done(groups[c], PACKETS, k, item.cache_key)]
        skipped += len(groups) - len(todo)
        shards = [CameraShard.start(cfg, rec, c, k, attrs[c], sel, with_h) for c in todo]
        _build_row(cfg, shards, sweeps, with_h)
        for shard in shards:
            shard.commit(cfg, groups[shard.camera], item.cache_key)
            done += shard.built
    _record_identity(groups, enc, cfg.packets.mode if with_h else "geom_only")
    return ItemResult(done=done, detail={"sweeps_decoded": sweeps.decoded,
                                         "shards_skipped": skipped})


@dataclass(frozen=True)
class Selection:
    """A recording's selection: a row per view, and (merging LiDARs) the accepted rows of
    each view and LiDAR by camera and frame (grouped once, read by every shard)."""

    views: pa.Table
    lidars: dict[str, dict[int, list[dict[str, Any]]]] = field(default_factory=dict)

    @classmethod
    def read(cls, folder: Path, merges: bool) -> Selection:
        """The selection tables of index `folder` (`selection_lidars` only when `merges`)."""
        views = read_index_table(folder / SELECTION_FILE, SELECTION)
        if not merges:
            return cls(views)
        table = read_index_table(folder / SELECTION_LIDARS_FILE, SELECTION_LIDARS)
        ok = table.filter(pc.equal(table["status"], "ok"))
        by: dict[str, dict[int, list[dict[str, Any]]]] = {}
        for r in ok.to_pylist():  # table (config) order within a view
            by.setdefault(r["camera"], {}).setdefault(r["frame"], []).append(r)
        return cls(views, by)

    def merged_rows(self, camera: str, region: slice) -> dict[int, list[dict[str, Any]]]:
        """frame -> accepted LiDAR rows of `camera`'s views in `region`, reference first;
        empty when not merging."""
        rows = self.lidars.get(camera, {})
        return {f: r for f, r in rows.items() if region.start <= f < region.stop}


@dataclass
class CameraShard:
    """One camera's shard k under construction: selection rows, output arrays, support sets."""

    recording: str
    camera: str
    shard: int
    attrs: GroupAttrs
    region: slice
    grid: GridSpec
    rows: dict[int, dict[str, Any]]
    g: np.ndarray  # (views of the shard, 6, H, W) float32, zero for views without a packet
    specs: list[Any]
    support: dict[int, Any] = field(default_factory=dict)
    h_rows: dict[int, np.ndarray] = field(default_factory=dict)  # view offset -> (k, C_u)
    built: int = 0
    lidar_rows: dict[int, list[dict[str, Any]]] = field(default_factory=dict)
    """Merging LiDARs: frame -> the accepted `selection_lidars` rows, reference first."""

    @classmethod
    def start(cls, cfg: M3GDConfig, rec: str, cam: str, shard: int, attrs: GroupAttrs,
              sel: Selection, with_h: bool) -> CameraShard:
        """Empty outputs (zeros) for the views of shard `shard` of camera `cam`."""
        region = shard_slice(shard, attrs.n_views, attrs.shard_views)
        rows = {r["frame"]: r for r in sel.views.filter(pc.equal(sel.views["camera"], cam))
                .to_pylist() if region.start <= r["frame"] < region.stop}
        grid = GridSpec(attrs.image_h, attrs.image_w, attrs.patch)
        specs = packet_arrays(grid, cfg.encoders.point_channels, with_h)
        g = np.zeros((region.stop - region.start, *specs[0].view_shape), np.float32)
        return cls(rec, cam, shard, attrs, region, grid, rows, g, specs,
                   lidar_rows=sel.merged_rows(cam, region))

    def valid(self) -> list[tuple[int, int]]:
        """(sweep, frame) of every view of the shard that has a selected sweep."""
        return [(r["sweep"], f) for f, r in self.rows.items() if r["status"] == "ok"]

    def commit(self, cfg: M3GDConfig, group: Any, key: str) -> None:
        """Write g (and h), the statistics part (frame order), then the done-mark."""
        stats = ShardStats(self.recording, self.camera)
        for frame in range(self.region.start, self.region.stop):
            row = self.rows.get(frame)
            if row is None or row["status"] != "ok":
                stats.add_view(frame, row["stamp_ns"] if row else 0, None,
                               row["dtau_s"] if row else None, None,
                               row["reason"] if row else "not_selected")
                continue
            stats.add_view(frame, row["stamp_ns"], row["sweep_stamp_ns"], row["dtau_s"],
                           self.support[frame], None)
        arrays = {spec.name: ensure_array(group, spec, self.attrs.n_views,
                                          self.attrs.shard_views, replace=True)
                  for spec in self.specs}
        if H_CELLS not in arrays:  # a geom_only run: h of an earlier full one is not its own
            drop_array(group, H_CELLS)
        with ShardWriter() as writer:  # shard files written while the statistics are
            write_region(arrays["g"], self.region.start, self.g, writer)
            if H_CELLS in arrays:
                width = arrays[H_CELLS].shape[2]
                write_packed(arrays[H_CELLS], self.region.start,
                             [self.h_rows.get(i, np.zeros((0, width), np.float32))
                              for i in range(len(self.g))], writer)
            stats.write(cfg.output_dir, self.shard)
        mark_shard_done(group, PACKETS, self.shard, key)


def _build_row(cfg: M3GDConfig, shards: list[CameraShard], sweeps: SweepCache,
               with_h: bool) -> None:
    """Packets of every view of one shard row, visited in sweep order.

    Views of all cameras that selected one sweep are built back to back, so each sweep
    is decoded and encoded once even when the cameras' shards are long.
    """
    jobs = sorted((sweep, i, frame) for i, sh in enumerate(shards) for sweep, frame in sh.valid())
    margin = cfg.packets.front_margin_m if cfg.packets.front_surface else None
    for sweep, i, frame in jobs:
        sh = shards[i]
        row = sh.rows[frame]
        points, T, dtau, feat = _view_points(sweep, row, sh.lidar_rows.get(frame, []), sweeps)
        sup = view_support(points, np.reshape(row["K_out"], (3, 3)), T,
                           (sh.grid.image_h, sh.grid.image_w),
                           min_depth_m=cfg.packets.min_depth_m, patch=sh.grid.patch)
        pkt = packet_from_support(sup, dtau, feat, mode="full" if with_h else "geom_only",
                                  front_margin_m=margin,
                                  front_margin_rel=cfg.packets.front_margin_rel)
        sh.g[frame - sh.region.start] = pkt.g
        g, h = pkt.g, pkt.h
        if with_h and g is not None and h is not None:  # pooled h is cell-major: packing
            rows = pack_rows(h[None], occupied_cells(g[None]))[0]  # gathers occupied rows
            sh.h_rows[frame - sh.region.start] = np.clip(rows, -F16_MAX, F16_MAX)
        sh.support[frame] = sup
        sh.built += 1


def _view_points(sweep: int, row: dict[str, Any], merged: list[dict[str, Any]],
                 sweeps: SweepCache) -> tuple[np.ndarray, np.ndarray, Any, Any]:
    """(points (N, 3), T_cam_points (4, 4), delta tau: the view's (s) or (N,) per point,
    features or None) of one view: its reference sweep as written, or, when several LiDARs'
    rows are accepted for it, their sweeps merged in the camera frame (`packets.merge`)."""
    if len(merged) < 2:  # one LiDAR (or the others rejected): exactly the single-LiDAR packet
        xyz, feat = sweeps.get(sweep)
        return xyz, np.reshape(row["T_cam_lidar"], (4, 4)), row["dtau_s"], feat
    parts = []
    for r in merged:
        xyz, feat = sweeps.get(r["sweep"])
        parts.append(SweepPart(xyz, np.reshape(r["T_cam_lidar"], (4, 4)), r["dtau_s"],
                               None if feat is None else feat.values))
    m = merge_in_camera(parts)
    feats = None if m.features is None else SweepFeatures(m.features)
    return m.xyz_cam, np.eye(4), m.delta_tau_s, feats


def _record_identity(groups: dict[str, Any], enc: Any | None, mode: str) -> None:
    """Store the point encoder identity and the packet mode in every group's attributes."""
    ident = enc.identity() if enc is not None else None
    for cam, group in groups.items():
        assert isinstance(group, zarr.Group)
        fresh = GroupAttrs.from_attrs(dict(group.attrs), cam)
        set_group_attrs(group, dataclasses.replace(fresh, point_encoder=ident,
                                                   packet_mode=mode).to_attrs())
