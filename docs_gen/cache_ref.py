"""The cache format reference: every array, dtype, chunking, attribute and g channel, as
Markdown, from `schemas.cache_layout` (the layout as code) and the default configuration."""

from __future__ import annotations

import dataclasses

from schemas import channels
from schemas.cache_layout import (
    CACHE_FORMAT_VERSION,
    CELL_BLOCK,
    F16_MAX,
    H_CELLS,
    ArraySpec,
    EncoderIdentity,
    GridSpec,
    GroupAttrs,
    LatentNorm,
    cell_block,
    image_arrays,
    latent_array,
    packet_arrays,
    root_attrs,
    view_meta_arrays,
)
from schemas.channels import VALIDITY, channel_index
from schemas.config import M3GDConfig

# what each array holds and which stage writes it
ARRAY_TEXT: dict[str, tuple[str, str]] = {
    "images": ("ingest", "rectified, resized RGB image of every indexed view (rejected "
               "views too)"),
    "stamp_ns": ("ingest", "image stamp, int64 ns"),
    "K": ("ingest", "intrinsics of the output image (row-major 3×3, pixels)"),
    "sweep_stamp_ns": ("select", "stamp of the selected LiDAR sweep, int64 ns (−1 for a view "
                       "without one)"),
    "dtau_s": ("select", "signed Δτ = sweep stamp − image stamp, seconds"),
    "T_world_cam": ("select", "camera pose in the odometry (world) frame at the image stamp"),
    "T_cam_lidar": ("select", "LiDAR → camera chain at the image stamp (eq. 7)"),
    "valid": ("select", "True for an accepted view; False for a rejected one"),
    "latents_l0": ("encode", "frozen image encoder latents (raw, not normalized)"),
    "g": ("packets", "packet geometry, the explicit channels below (eq. 9)"),
    H_CELLS: ("packets", "packed point features of the occupied cells (eq. 10)"),
}

def _codec(spec: ArraySpec) -> str:
    return {"raw": "none", "zstd": "zstd level 1"}[spec.codec]


def _row(spec: ArraySpec, shard_views: int) -> str:
    stage, text = ARRAY_TEXT[spec.name]
    shards = spec.shards(shard_views)
    shard_text = f"`{shards}`" if shards else "none (one chunk per shard of views)"
    return (f"| `{spec.name}` | `{spec.dtype}` | `(N, {', '.join(map(str, spec.view_shape))})` "
            f"| `{', '.join(spec.dims)}` | `{spec.chunks(shard_views)}` | {shard_text} | "
            f"{_codec(spec)} | {stage} | {text} |").replace("(N, )", "(N,)")


def default_arrays(cfg: M3GDConfig) -> list[ArraySpec]:
    """Every array of one cache group under configuration `cfg`, in write order."""
    grid = GridSpec(cfg.ingest.out_height, cfg.ingest.out_width)
    return [*image_arrays(grid), *view_meta_arrays(),
            latent_array(grid, cfg.encoders.image_channels, cfg.cache.latent_dtype),
            *packet_arrays(grid, cfg.encoders.point_channels, with_h=True)]


def render() -> str:
    """The cache format page (Markdown)."""
    cfg = M3GDConfig()
    sections = (_intro(cfg), _arrays(cfg), _channels(), _h_cells(cfg), _rejected(),
                _latent_norm(), _attributes())
    return "\n".join(line for section in sections for line in section)


def _grid(cfg: M3GDConfig) -> GridSpec:
    return GridSpec(cfg.ingest.out_height, cfg.ingest.out_width)


def _intro(cfg: M3GDConfig) -> list[str]:
    """Title, format version and the store's layout."""
    sv = cfg.cache.shard_views
    return [
        "# Cache format",
        "",
        f"Generated from `schemas/cache_layout.py` each time the site is built. Cache format "
        f"version **{CACHE_FORMAT_VERSION}**: a Zarr v3 store `out/cache.zarr` that "
        "zarr-python, tensorstore and xarray read without m3gd "
        "([reading it with zarr-python alone]"
        "(../guides/trainers.md#reading-the-cache-with-zarr-python-alone)).",
        "",
        "## Layout",
        "",
        "```",
        "cache.zarr/                      root group: format version, latent_norm",
        "  <recording>/<camera>/          one group per recording and camera",
        "    images, stamp_ns, K          ingest",
        "    sweep_stamp_ns, dtau_s, T_world_cam, T_cam_lidar, valid    select",
        "    latents_l0                   encode",
        "    g, h_cells                   packets",
        "```",
        "",
        "Every array has the N views of its group on axis 0, in image-stamp order (the `frame`",
        "column of the tables). Per-view arrays are chunked one view per chunk and sharded",
        f"`cache.shard_views` views per shard file (default {sv}); small metadata arrays are",
        "chunked one shard of views per chunk, unsharded. Every stored chunk ends with its",
        "CRC32C (zarr's `crc32c` codec, cache format 3), checked by every reader; in the",
        "uncompressed shards m3gd writes, each chunk starts on a 64-byte boundary (zero",
        "padding after the CRC, located like every chunk by the shard index). Completion",
        "marks live beside the store in `out/cache_done/` (a Zarr reader never sees them).",
        "",
    ]


def _arrays(cfg: M3GDConfig) -> list[str]:
    """The table of every array of a group under the default configuration."""
    grid, sv = _grid(cfg), cfg.cache.shard_views
    return [
        f"## Arrays (default configuration: {cfg.ingest.out_height} × {cfg.ingest.out_width} "
        f"images, a {grid.grid_h} × {grid.grid_w} latent grid of {grid.patch} px patches, "
        f"C = {cfg.encoders.image_channels}, C_u = {cfg.encoders.point_channels}, "
        f"shard_views = {sv})",
        "",
        "| array | dtype | shape | dimensions | chunk | shard | compression | written by | "
        "holds |",
        "|---|---|---|---|---|---|---|---|---|",
        *(_row(spec, sv) for spec in default_arrays(cfg)),
        "",
        "Shapes follow the configuration: H × W is `ingest.out_height / 14` × "
        "`ingest.out_width / 14`, C is `encoders.image_channels`, C_u "
        "`encoders.point_channels`, the latent dtype `cache.latent_dtype`. Array dimension "
        "names are stored in each array's metadata (`dimension_names`), so xarray opens a "
        "group with named dimensions. float16 latents and h are clipped to ±"
        f"{F16_MAX:g} (the float16 range) before storage, and every float block is checked "
        "finite as it is written (`store/finite.py`): no NaN or Inf enters the cache.",
        "",
    ]


_NUMBER_WORDS = {4: "four", 5: "five", 6: "six", 7: "seven", 8: "eight"}


def _channels() -> list[str]:
    """The g channel table, from schemas.channels.PACKET_CHANNELS."""
    table = channels.PACKET_CHANNELS  # read when called: the table as it is now
    count = _NUMBER_WORDS.get(len(table), str(len(table)))
    return [
        f"## g: the {count} explicit packet channels (eq. 9)",
        "",
        "`g[n, k, row, col]`, float32, zero in every channel on a cell without support:",
        "",
        "| k | name | value on an occupied cell | unit |",
        "|---|---|---|---|",
        *(f"| {k} | `{c.name}` | {c.meaning} | {c.unit} |"
          for k, c in enumerate(table)),
        "",
        f"A cell is *occupied* when `g[n, {channel_index(VALIDITY)}] == 1`. The mean depth is "
        "over the points that project into the cell (beyond `packets.min_depth_m`; with "
        "`packets.front_surface` only those within the front-surface margin of the nearest).",
        "",
    ]


def _h_cells(cfg: M3GDConfig) -> list[str]:
    """The packed point features and how to rebuild dense h."""
    grid = _grid(cfg)
    n_cells = grid.grid_h * grid.grid_w
    valid = channel_index(VALIDITY)
    return [
        "## h_cells: packed point features (eq. 10)",
        "",
        f"The dense packet features h (C_u, H, W) are zero on every unoccupied cell, so the "
        f"cache stores only the occupied ones: `h_cells[n]` is ({n_cells}, C_u) for the default "
        "grid (H·W rows). Row r holds the C_u features of the r-th occupied cell of view n, "
        f"cells taken in **row-major (row, col) order** of `g[n, {valid}] == 1`; rows after the "
        f"last occupied cell are zero. They are chunked {CELL_BLOCK} rows per chunk (at most; "
        f"{cell_block(n_cells)} for the default grid: the largest divisor of H·W up to "
        f"{CELL_BLOCK}), and chunks past a view's last occupied cell are never written (absent "
        "chunks read as the fill value 0). To rebuild dense h:",
        "",
        "```python",
        f"occ = g[n, {valid}] > 0.5                       # (H, W) bool",
        "k = int(occ.sum())                        # occupied cells of view n",
        "h = np.zeros((H, W, C_u), h_cells.dtype)",
        "h[occ] = h_cells[n, :k]                   # boolean indexing is row-major",
        "```",
        "",
        "In m3gd: `schemas.packed_cells.unpack_rows`, or `store.cache_io.read_clip(group, "
        "['h'], frames)`. A geometry-only reader never touches `h_cells`.",
        "",
    ]


def _rejected() -> list[str]:
    """What a rejected view keeps in the cache."""
    return [
        "## Rejected views",
        "",
        "A view rejected by select (Δτ beyond `select.max_abs_dt_s`, an odometry gap, no "
        "sweep) keeps its place on axis 0: its image, stamp and K are stored, `valid` is "
        "False, its latents, g and h rows are zeros (the encoders never see it), and its "
        "`sweep_stamp_ns`, `dtau_s` and transforms are those of its `selection` row (identity "
        "transforms and sweep −1 there when no sweep exists). Readers skip views with "
        "`valid == False`; the clip index never uses them. Messages rejected at ingest "
        "(a corrupt JPEG, ...) never become views.",
        "",
    ]


LATENT_NORM_TEXT = {
    "mean": "per-channel mean (C floats)",
    "std": "per-channel standard deviation (C floats)",
    "count": "latent cells it was computed over (valid views × H × W)",
    "views": "valid views it was computed over (the sum of `groups`)",
    "groups": "`<recording>/<camera>` → valid views of that group it covers",
}
"""The fields of the root attribute `latent_norm` (`schemas.cache_layout.LatentNorm`)."""


def _latent_norm() -> list[str]:
    """Where the latent normalization lives, what it records and how a trainer applies it."""
    example = LatentNorm([0.0], [1.0], 0, {"<recording>/<camera>": 0}).to_attrs()
    return [
        "## Latent normalization",
        "",
        "Stored latents are the encoder's raw output (float16 by default), **not** "
        "normalized. The stats stage merges per-shard channel statistics over the valid "
        "views of every recording and writes them in the **root group's** attributes:",
        "",
        "```json",
        '"latent_norm": {"mean": [C floats], "std": [C floats], "count": cells, '
        '"views": valid views, "groups": {"<recording>/<camera>": valid views}}',
        "```",
        "",
        "| field | meaning |",
        "|---|---|",
        *(f"| `{k}` | {LATENT_NORM_TEXT[k]} |" for k in example),
        "",
        "The trainer normalizes per channel, `(latents - mean[:, None, None]) / std[:, None, "
        "None]` (`model.dataset.latent_norm`, `ClipStream`); decode with the inverse. Before "
        "it does, the valid views recorded per group are checked against the cache's `valid` "
        "arrays (and every group whose clips are read must be covered): a normalization of "
        "other views, or one recorded without `groups` (an earlier format), is refused in one "
        "line; `m3gd run` recomputes it (`m3gd run --force stats` when the run is up to "
        "date). `m3gd verify` reports the same mismatch and forgets the normalization so "
        "that the next run recomputes it.",
        "",
    ]


def _attributes() -> list[str]:
    """The root and group attributes and the encoder identity."""
    return [
        "## Attributes",
        "",
        "Root group:",
        "",
        "| attribute | value |",
        "|---|---|",
        *(f"| `{k}` | `{v!r}` |" for k, v in root_attrs().items()),
        "| `latent_norm` | written by the stats stage (above) |",
        "",
        "Each `<recording>/<camera>` group (`schemas.cache_layout.GroupAttrs`):",
        "",
        "| attribute | type | meaning |",
        "|---|---|---|",
        *(f"| `{f.name}` | `{_type(f.type)}` | {GROUP_ATTR_TEXT.get(f.name, '')} |"
          for f in dataclasses.fields(GroupAttrs)),
        "| `m3gd_kind`, `m3gd_format_version` | str, int | `cache_group`, "
        f"{CACHE_FORMAT_VERSION} |",
        "",
        "An encoder identity (`EncoderIdentity`) has the keys "
        + ", ".join(f"`{f.name}`" for f in dataclasses.fields(EncoderIdentity))
        + ": a cache written by embedded weight-free encoders says so "
        "(`name` `patch` / `fpfh`, `pretrained` false).",
        "",
        "Readers refuse a group or root of another format version with one line; format 1 "
        "(dense h) is refused: rebuild the packets.",
        "",
    ]


def _type(t: object) -> str:
    return str(t).replace("'", "")


GROUP_ATTR_TEXT = {
    "recording": "recording name (its mission folder name)",
    "camera": "camera name",
    "n_views": "N, views on axis 0",
    "image_h": "image height, pixels",
    "image_w": "image width, pixels",
    "patch": "pixels per latent cell side (14)",
    "shard_views": "views per shard file",
    "image_encoder": "identity of the image encoder that wrote `latents_l0`",
    "point_encoder": "identity of the point encoder that wrote `h_cells`",
    "packet_mode": "packet mode of the stored packets (`full`, `geom_only`, ...)",
    "latent_stats": "reserved (written empty; the normalization is the root's `latent_norm`)",
    "format_version": "cache format version",
}
