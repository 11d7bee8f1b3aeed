"""`m3gd align`: the 2D-3D alignment diagnostics (paper §VI-A, Table 1) over the cache.

For each chosen feature pair (X, Y), e.g. ("latents_l0", "h"): image latents against pooled
point features, every valid view of every `<recording>/<camera>` group is one image; its
supported cells are the cells whose packet validity channel g[0] is 1 (n_q > 0), and on those
cells X (n, C) and Y (n, C_u) are compared by `packets.alignment.alignment_report`: macro
averages over images, images with fewer than `min_cells` supported cells (or with a constant
side) excluded and counted, every metric beside its within-image permutation null, CKA also
debiased. The cache is streamed one shard at a time (one shard of each needed array in
memory), in group then frame order.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from packets.alignment import AlignmentReport, alignment_report
from schemas.cache_layout import GroupAttrs, check_root_attrs, shard_regions, stored_arrays
from schemas.errors import DataError, MissingInputError
from schemas.layout import OutputLayout
from schemas.packed_cells import occupied_cells
from schemas.tables import ALIGNMENT, write_table
from schemas.versioning import KIND_KEY
from store.cache_io import node_attrs, read_clip, read_views
from store.cache_store import cache_path

ALIGNMENT_FILE = "alignment.parquet"
DEFAULT_PAIRS: tuple[tuple[str, str], ...] = (("latents_l0", "h"),)
DEFAULT_N_PERM = 20
_FEATURE = re.compile(r"latents_l\d+|g|h")


@dataclass(frozen=True)
class CacheGroup:
    """One `<recording>/<camera>` group of the cache: its directory and attributes."""

    path: Path
    attrs: GroupAttrs


def cache_groups(output_dir: Path) -> list[CacheGroup]:
    """Every recording-camera group of `<output_dir>/cache.zarr`, sorted by path."""
    root = cache_path(output_dir)
    if not (root / "zarr.json").exists():
        raise MissingInputError(f"{root}: no m3gd cache here; run the encode and packets stages")
    check_root_attrs(node_attrs(root), str(root))
    groups = []
    for meta in sorted(root.glob("*/*/zarr.json")):
        attrs = node_attrs(meta.parent)
        if attrs.get(KIND_KEY) == "cache_group":
            groups.append(CacheGroup(meta.parent, GroupAttrs.from_attrs(attrs, str(meta.parent))))
    return groups


def pair_name(pair: tuple[str, str]) -> str:
    """Table label of a feature pair, 'X:Y' (e.g. 'latents_l0:h')."""
    return f"{pair[0]}:{pair[1]}"


def check_pairs(pairs: list[tuple[str, str]]) -> None:
    """Refuse feature names other than latents_l<k>, g and h."""
    if not pairs:
        raise DataError("no feature pairs given; e.g. [('latents_l0', 'h')]")
    for pair in pairs:
        for name in pair:
            if not _FEATURE.fullmatch(name):
                raise DataError(f"feature pair {pair}: {name!r} is not latents_l<k>, g or h")


def _read_finite(group: CacheGroup, names: tuple[str, ...],
                 frames: list[int]) -> dict[str, np.ndarray]:
    """Views `frames` of features `names` as float32 (k, C, H, W), read together (one clip
    read: g once, h unpacked from `h_cells`); ValueError names a view with NaN or Inf."""
    for name in names:
        for array in stored_arrays(name):
            if not (group.path / array / "zarr.json").exists():
                raise MissingInputError(f"{group.path / array}: array {array!r} missing in "
                                        f"cache group {group.path.name}")
    out = {}
    for name, data in read_clip(group.path, list(names), frames).items():
        values = (np.moveaxis(data, -1, 1) if name == "h" else data).astype(np.float32)
        bad = ~np.isfinite(values.reshape(len(frames), -1)).all(axis=1)
        if bad.any():
            raise DataError(f"{group.path / stored_arrays(name)[0]}: view "
                             f"{frames[int(np.flatnonzero(bad)[0])]} has NaN or Inf")
        out[name] = values
    return out


def image_features(output_dir: Path, pair: tuple[str, str],
                   max_images: int | None = None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Per valid view: (X (n, C_x), Y (n, C_y)) float32 on its n supported cells.

    Streams shard by shard; views whose `valid` flag is False are skipped; at most
    `max_images` views are yielded (the first in group, then frame order).
    """
    yielded = 0
    for group in cache_groups(output_dir):
        attrs = group.attrs
        for start, stop in shard_regions(attrs.n_views, attrs.shard_views):
            frames = list(range(start, stop))
            valid = read_views(group.path / "valid", frames).astype(bool)
            keep = [f for f, ok in zip(frames, valid, strict=True) if ok]
            if not keep:
                continue
            arrays = _read_finite(group, tuple(dict.fromkeys(("g", *pair))), keep)
            supported = occupied_cells(arrays["g"])
            for i in range(len(keep)):
                if max_images is not None and yielded >= max_images:
                    return
                mask = supported[i]
                yield arrays[pair[0]][i][:, mask].T, arrays[pair[1]][i][:, mask].T
                yielded += 1


def report_rows(pair: tuple[str, str], report: AlignmentReport) -> list[dict[str, object]]:
    """Rows of the ALIGNMENT table for one pair: value beside the mean permutation null."""
    excluded = report.n_excluded_small + report.n_excluded_constant
    return [{"pair": pair_name(pair), "metric": m.name, "value": m.value,
             "null_value": m.null_mean, "images": m.n_images, "excluded_images": excluded}
            for m in report.metrics]


def count_views(output_dir: Path, max_images: int | None = None) -> int:
    """Valid views one pair streams (at most `max_images`): the total of a progress line."""
    n = sum(int(read_views(g.path / "valid", list(range(g.attrs.n_views))).sum())
            for g in cache_groups(output_dir))
    return n if max_images is None else min(n, max_images)


def _counted(views: Iterator[tuple[np.ndarray, np.ndarray]],
             on_view: Callable[[int], None] | None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """`views`, calling `on_view(1)` after each one."""
    for view in views:
        yield view
        if on_view is not None:
            on_view(1)


def run_alignment(output_dir: Path, pairs: list[tuple[str, str]], min_cells: int = 3,
                  n_perm: int = DEFAULT_N_PERM, seed: int = 0,
                  max_images: int | None = None,
                  on_view: Callable[[int], None] | None = None) -> pa.Table:
    """Alignment diagnostics of every pair over the cache; a table of schema ALIGNMENT.

    One row per (pair, metric): `value` the macro mean over images, `null_value` the mean of
    the permutation null (cells of Y shuffled within each image, `n_perm` draws seeded by
    `seed`), `images` the images behind the metric, `excluded_images` the images with fewer
    than `min_cells` supported cells or a constant side. A metric with no images reads 0.0
    with images = 0. Each pair streams the cache once; `on_view(1)` is called per view read
    (progress).
    """
    check_pairs(pairs)
    if max_images is not None and max_images < 1:
        raise DataError(f"max_images={max_images} must be >= 1 (or None for all)")
    rows: list[dict[str, object]] = []
    for pair in pairs:
        report = alignment_report(_counted(image_features(output_dir, pair, max_images),
                                           on_view), min_cells=min_cells, n_perm=n_perm,
                                  seed=seed)
        rows.extend(report_rows(pair, report))
    return pa.Table.from_pylist(rows, schema=ALIGNMENT)


def write_alignment(output_dir: Path, table: pa.Table) -> Path:
    """Write the alignment table to `<output_dir>/stats/alignment.parquet`; return the path."""
    path = OutputLayout(output_dir).stats / ALIGNMENT_FILE
    write_table(table, ALIGNMENT, path)
    return path
