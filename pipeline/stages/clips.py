"""Clips stage: the train / eval clip index, split by recording or by time segment within
each recording (`clips.split`, `model.clips.split_mode`)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa
import zarr

from model.clips import (
    sample_clips,
    segment_frames,
    segment_gap,
    split_mode,
    split_recordings,
)
from pipeline.run.keys import ItemKey
from pipeline.run.reads import Reads, StoreReads
from pipeline.run.stage import Item, ItemResult
from pipeline.stages.common import cache_key, upstream_key
from schemas import stages as stage_table
from schemas.cache_layout import PACKETS, GroupAttrs, shard_regions
from schemas.config import M3GDConfig
from schemas.layout import CACHE_DIRNAME, DONE_DIRNAME
from schemas.missions import recording_names
from schemas.tables import CLIPS, CLIPS_SPLIT_KEY, write_table
from store.cache_io import read_views
from store.cache_store import camera_groups, open_root, stage_marked

CLIPS_ITEM = ItemKey.cross(stage_table.CLIPS.name)

CLIPS_READS = StoreReads(Reads((CACHE_DIRNAME, DONE_DIRNAME), ("valid", "T_world_cam")))
"""The cache metadata and done-marks, and the valid flags and poses the clips are drawn from."""


def plan_clips(cfg: M3GDConfig) -> list[Item]:
    """A single item: the clip index of the whole run."""
    return [Item(CLIPS_ITEM, cache_key(upstream_key(cfg), cfg.clips, recording_names(cfg)))]


def _camera_clips(group: zarr.Group, split: str, count: int, cfg: M3GDConfig,
                  seed: int) -> list[dict[str, object]]:
    """Clip rows of one recording-camera group: of `split` (train or eval) under the
    recording split, of both under the segment split ("segment": `count` eval clips)."""
    attrs = GroupAttrs.from_attrs(dict(group.attrs), str(group.path))
    path = cfg.layout.cache / group.path
    frames = list(range(attrs.n_views))
    if not frames:
        return []
    valid = np.flatnonzero(read_views(path / "valid", frames)).astype(np.int64)
    centres = read_views(path / "T_world_cam", frames)[:, :3, 3]
    c = cfg.clips
    if split == "segment":
        parts = segment_frames(valid, attrs.n_views, c.eval_fraction,
                               segment_gap(c.views, c.gap_max))
        draws = [("train", parts["train"], attrs.n_views, seed), ("eval", parts["eval"], count,
                                                                  seed + 1)]
    else:
        draws = [(split, valid, count if split == "eval" else attrs.n_views, seed)]
    rows = []
    for name, frames_of, n, s in draws:
        clips = sample_clips(frames_of, centres, n, name, c.views, c.gap_min, c.gap_max, s)
        rows += [{"split": name, "recording": attrs.recording, "camera": attrs.camera,
                  "frames": list(k.frames), "is_target": list(k.is_target),
                  "max_baseline_m": k.max_baseline_m,
                  "hard": k.max_baseline_m > c.hard_baseline_m} for k in clips]
    return rows


def split_note(mode: str, cfg: M3GDConfig, recordings: int) -> str | None:
    """The line saying the clips are split by segment (why, where the gap is), or None."""
    if mode != "segment":
        return None
    c = cfg.clips
    why = ("clips.split: segment" if c.split == "segment" else
           f"{recordings} recording{'s' if recordings != 1 else ''}, too few to hold one out "
           "(clips.split: auto)")
    return (f"clips split by time segment within each recording ({why}): eval the last "
            f"{c.eval_fraction:.0%} of each camera's frames, train the frames more than "
            f"{segment_gap(c.views, c.gap_max)} before it")


def run_clips(cfg: M3GDConfig, item: Item) -> ItemResult:
    """Split recordings (or segments of them), sample train and eval clips, write
    `clips.parquet` (its split recorded in the metadata, `CLIPS_SPLIT_KEY`). Under
    `clips.split: auto`, a segment split that leaves either side without a clip (recordings
    too short for the gap) falls back to the recording split, saying so."""
    names = recording_names(cfg)
    mode = split_mode(cfg.clips.split, len(names), cfg.clips.eval_fraction)
    rows, warnings = _draw(cfg, names, mode)
    note = split_note(mode, cfg, len(names))
    sides = {r["split"] for r in rows}
    if mode == "segment" and cfg.clips.split == "auto" and sides != {"train", "eval"}:
        gap = segment_gap(cfg.clips.views, cfg.clips.gap_max)
        note = (f"clips split by recording: {len(names)} recording, too short for a segment "
                f"split ({'no ' + ' and no '.join(sorted({'train', 'eval'} - sides))} clip with "
                f"a gap of {gap} frames, (clips.views - 1) * clips.gap_max); lower "
                "clips.gap_max or raise clips.eval_fraction to split it by segment")
        mode = "recording"
        rows, warnings = _draw(cfg, names, mode)
    for i, row in enumerate(rows):
        row["clip_id"] = i
    schema = CLIPS.with_metadata({**(CLIPS.metadata or {}), CLIPS_SPLIT_KEY.encode():
                                  mode.encode()})
    write_table(pa.Table.from_pylist(rows, schema=CLIPS), schema, cfg.layout.clips)
    n_eval = sum(r["split"] == "eval" for r in rows)
    return ItemResult(done=len(rows), detail={"train": len(rows) - n_eval, "eval": n_eval,
                                              "split_by": mode},
                      warnings=[note, *warnings] if note else warnings)


def _draw(cfg: M3GDConfig, names: list[str], mode: str
          ) -> tuple[list[dict[str, object]], list[str]]:
    """Clip rows of every recording under split `mode`, and warnings (incomplete packets)."""
    split = (split_recordings(names, cfg.clips.eval_fraction, cfg.clips.seed)
             if mode == "recording" else dict.fromkeys(names, "segment"))
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
            per_rec = cfg.clips.eval_clips_per_recording  # split exactly across cameras
            share = per_rec // len(cams) + (1 if c_i < per_rec % len(cams) else 0)
            seed = cfg.clips.seed * 1000 + r_i * 10 + c_i
            rows.extend(_camera_clips(group, split[rec], share, cfg, seed))
    return rows, warnings


def _packets_complete(group: Any, attrs: GroupAttrs) -> bool:
    """Whether the packets stage marked every shard of a recording-camera group done."""
    return stage_marked(group, PACKETS, len(shard_regions(attrs.n_views, attrs.shard_views)))
