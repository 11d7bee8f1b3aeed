"""The Zarr v3 cache layout as code: array names, shapes, dtypes, chunks, shards, attributes.

Store: `<output_dir>/cache.zarr`. Root attributes carry the format version.
One group per recording and camera at `<recording>/<camera>`; in each group the
per-view arrays below, all with N views on axis 0, one view per chunk (packed h_cells:
CELL_BLOCK cells of one view per chunk) and `shard_views` views per shard. Metadata arrays
(small) are chunked by shard.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal

from schemas import stages as stage_table
from schemas.layout import CACHE_DIRNAME as CACHE_DIRNAME  # re-exported: its old home
from schemas.versioning import KIND_KEY, VERSION_KEY, UnknownSchemaVersion, check_version

CACHE_FORMAT_VERSION = 3
"""3: every chunk of every array ends with its CRC32C (zarr v3's `crc32c` codec, inside the
shard for sharded arrays), checked by every reader; 2: packet features stored for occupied
cells only (`h_cells`, see schemas.packed_cells), no chunk checksums (refused: rebuild, see
`OLD_FORMATS`); 1: dense h (N, C_u, H, W) with a transpose codec (refused)."""
OLD_FORMATS = {2: "its chunks carry no checksums", 1: "its packets are dense"}
"""Why a cache of an earlier format is refused, by version (it is rebuilt: `m3gd run` says
how)."""
GROUP_TEMPLATE = "{recording}/{camera}"
SHARDS_DONE_ATTR = "shards_done"
_T_DIMS = ("view", "t_row", "t_col")


# Codec chains, chosen by measurement (docs/benchmarks.md, `m3gd bench cache`), each ending
# with the `crc32c` codec (format 3):
# "raw": no compression (dense latents: zstd saved ~8% and cut reads ~3x; packed h_cells,
#   whose sparsity is carried by chunks that are never written);
# "zstd": zstd level 1 (small metadata and g);
Codec = Literal["raw", "zstd"]

WriterStage = str
"""A stage that writes cache arrays (a row of `schemas.stages.STAGE_TABLE` with arrays)."""
INGEST: WriterStage = stage_table.INGEST.name
SELECT: WriterStage = stage_table.SELECT.name
ENCODE: WriterStage = stage_table.ENCODE.name
PACKETS: WriterStage = stage_table.PACKETS.name


@dataclass(frozen=True)
class ArraySpec:
    """One per-view array: name, dtype, per-view shape, codec chain and whether sharded."""

    name: str
    dtype: str
    view_shape: tuple[int, ...]
    codec: Codec
    dims: tuple[str, ...]
    sharded: bool = True
    view_chunk: tuple[int, ...] | None = None
    writer_stage: WriterStage | None = None
    """The stage that writes the array (and whose done-marks cover its shards): set by the
    builder functions below from the stage table (`schemas.stages`), where each array's
    writer is declared."""

    def shape(self, n_views: int) -> tuple[int, ...]:
        """Full array shape for `n_views` views."""
        return (n_views, *self.view_shape)

    def chunks(self, shard_views: int) -> tuple[int, ...]:
        """Inner chunk: one view (or `view_chunk` of one view) when sharded; else one shard
        of views (metadata)."""
        if not self.sharded:
            return (shard_views, *self.view_shape)
        return (1, *(self.view_chunk or self.view_shape))

    def shards(self, shard_views: int) -> tuple[int, ...] | None:
        """Shard shape: `shard_views` views, or None for unsharded arrays."""
        return (shard_views, *self.view_shape) if self.sharded else None


@dataclass(frozen=True)
class GridSpec:
    """Image size in pixels and the latent grid it maps to (patch px per cell)."""

    image_h: int
    image_w: int
    patch: int = 14

    @property
    def grid_h(self) -> int:
        """Latent grid height in cells."""
        return self.image_h // self.patch

    @property
    def grid_w(self) -> int:
        """Latent grid width in cells."""
        return self.image_w // self.patch


def _written_by(specs: list[ArraySpec]) -> list[ArraySpec]:
    """`specs` with the writer the stage table declares for each (`schemas.stages`)."""
    return [replace(s, writer_stage=writer_stage(s.name)) for s in specs]


def image_arrays(grid: GridSpec) -> list[ArraySpec]:
    """Arrays written by ingest: rectified images and per-view metadata."""
    return _written_by([
        ArraySpec("images", "uint8", (grid.image_h, grid.image_w, 3), "raw",
                  ("view", "y", "x", "rgb")),
        ArraySpec("stamp_ns", "int64", (), "raw", ("view",), sharded=False),
        ArraySpec("K", "float64", (3, 3), "raw", ("view", "k_row", "k_col"), sharded=False),
    ])


def view_meta_arrays() -> list[ArraySpec]:
    """Per-view selection metadata, written by the select stage."""
    return _written_by([
        ArraySpec("sweep_stamp_ns", "int64", (), "raw", ("view",), sharded=False),
        ArraySpec("dtau_s", "float64", (), "raw", ("view",), sharded=False),
        ArraySpec("T_world_cam", "float64", (4, 4), "raw", _T_DIMS, sharded=False),
        ArraySpec("T_cam_lidar", "float64", (4, 4), "raw", _T_DIMS, sharded=False),
        ArraySpec("valid", "bool", (), "raw", ("view",), sharded=False),
    ])


LATENT_PREFIX = stage_table.LATENT_PREFIX
"""Latent arrays are named `latents_l<level>`."""


def latent_array(grid: GridSpec, channels: int, dtype: str, level: int = 0) -> ArraySpec:
    """Image latents (N, C, H, W); dense, so stored uncompressed (zstd barely shrinks them:
    docs/benchmarks.md, 'Design measurements')."""
    return ArraySpec(f"{LATENT_PREFIX}{level}", dtype, (channels, grid.grid_h, grid.grid_w),
                     "raw", ("view", f"latent_channel_l{level}", "row", "col"),
                     writer_stage=writer_stage(f"{LATENT_PREFIX}{level}"))


H_CELLS = "h_cells"
"""Array of packed packet features (N, H*W, C_u); see schemas.packed_cells."""
CELL_BLOCK = 64
"""Packed rows per inner chunk of `h_cells` (at most; see `cell_block`). A view's chunks past
its last occupied cell are never written (absent from the shard, read as zeros), so storage
and reads follow occupancy in blocks of this many cells; measured against 32 and a one-view
LZ4 chunk in docs/benchmarks.md."""


def cell_block(n_cells: int) -> int:
    """Rows per `h_cells` chunk: the largest divisor of `n_cells` up to CELL_BLOCK (a shard
    must hold whole chunks); 64 for the 16 x 24 grid of 224 x 336 images."""
    return max(d for d in range(1, min(CELL_BLOCK, n_cells) + 1) if n_cells % d == 0)


def stored_arrays(name: str) -> tuple[str, ...]:
    """The arrays a reader's name is stored as: 'h' is `h_cells` placed by g, others as is."""
    return (H_CELLS, "g") if name == "h" else (name,)


def packet_arrays(grid: GridSpec, point_channels: int, with_h: bool) -> list[ArraySpec]:
    """Packet geometry g (N, 6, H, W) float32 and features `h_cells` (N, H*W, C_u) float16.

    h is stored for occupied cells only (g[0] == 1), packed in row-major cell order
    (schemas.packed_cells), uncompressed in chunks of CELL_BLOCK rows of which only those
    holding occupied cells exist; g is zstd-compressed (mostly empty cells).
    """
    from schemas.channels import n_g  # the one channel table

    specs = [ArraySpec("g", "float32", (n_g(), grid.grid_h, grid.grid_w), "zstd",
                       ("view", "g_channel", "row", "col"))]
    if with_h:
        n_cells = grid.grid_h * grid.grid_w
        specs.append(ArraySpec(H_CELLS, "float16", (n_cells, point_channels), "raw",
                               ("view", "cell_slot", "h_channel"),
                               view_chunk=(cell_block(n_cells), point_channels)))
    return _written_by(specs)


def layout_arrays(with_h: bool = True) -> list[ArraySpec]:
    """Every array of a cache group (latents: level 0), on a nominal grid: for their names,
    writers and codecs (shapes follow the run's grid and channels)."""
    grid = GridSpec(14, 14)
    return [*image_arrays(grid), *view_meta_arrays(), latent_array(grid, 1, "float16"),
            *packet_arrays(grid, 1, with_h)]


def writer_stage(array: str) -> WriterStage | None:
    """The stage that writes `array` of a cache group (any latent level: encode); None for
    an array the stage table does not declare."""
    spec = stage_table.writer_of_array(array)
    return None if spec is None else spec.name


def arrays_written_by(stage: str, with_h: bool = True) -> tuple[str, ...]:
    """Names of the arrays `stage` writes in every cache group (latents: level 0)."""
    return tuple(s.name for s in layout_arrays(with_h) if s.writer_stage == stage)


@dataclass(frozen=True)
class EncoderIdentity:
    """Which frozen encoder produced an array."""

    name: str
    version: str
    weights_hash: str
    pretrained: bool
    channels: int


@dataclass
class GroupAttrs:
    """Attributes of one `<recording>/<camera>` group."""

    recording: str
    camera: str
    n_views: int
    image_h: int
    image_w: int
    patch: int
    shard_views: int
    image_encoder: EncoderIdentity | None = None
    point_encoder: EncoderIdentity | None = None
    packet_mode: str | None = None
    latent_stats: dict[str, list[float]] = field(default_factory=dict)
    format_version: int = CACHE_FORMAT_VERSION

    def to_attrs(self) -> dict[str, Any]:
        """JSON-compatible attributes (with the kind and version keys)."""
        out = asdict(self)
        out[KIND_KEY] = "cache_group"
        out[VERSION_KEY] = CACHE_FORMAT_VERSION
        return out

    @classmethod
    def from_attrs(cls, attrs: dict[str, Any], where: str) -> GroupAttrs:
        """Parse group attributes; refuse an unknown format version (an earlier one with
        what to do)."""
        check_cache_version(attrs.get(VERSION_KEY), "cache group", where)
        raw = {k: v for k, v in attrs.items() if k in cls.__dataclass_fields__}
        for key in ("image_encoder", "point_encoder"):
            if raw.get(key) is not None:
                raw[key] = EncoderIdentity(**raw[key])
        return cls(**raw)


def root_attrs() -> dict[str, Any]:
    """Attributes of the cache root group."""
    return {KIND_KEY: "cache", VERSION_KEY: CACHE_FORMAT_VERSION}


def check_root_attrs(attrs: dict[str, Any], where: str) -> None:
    """Refuse a cache root of an unknown format (an earlier one with what to do)."""
    check_cache_version(attrs.get(VERSION_KEY), "cache", where)


def check_cache_version(found: object, kind: str, where: str) -> None:
    """Refuse a cache node whose format is not CACHE_FORMAT_VERSION; for an earlier format,
    say what to do (`OLD_FORMATS`)."""
    old = OLD_FORMATS.get(found) if isinstance(found, int) else None
    if old is not None:
        raise UnknownSchemaVersion(f"{where}: {kind} format version {found} is not supported "
                                   f"by this m3gd (reads version {CACHE_FORMAT_VERSION}: "
                                   f"{old})")
    check_version(found, CACHE_FORMAT_VERSION, kind, where)


def shard_regions(n_views: int, shard_views: int) -> list[tuple[int, int]]:
    """Half-open view ranges [start, stop) of every shard, in order."""
    return [(s, min(s + shard_views, n_views)) for s in range(0, n_views, shard_views)]


def region_for(shard: int, n_views: int, shard_views: int) -> tuple[int, int]:
    """The view range of shard index `shard`; raises IndexError when out of range."""
    regions = shard_regions(n_views, shard_views)
    if not 0 <= shard < len(regions):
        raise IndexError(f"shard {shard} out of range 0..{len(regions) - 1} for {n_views} views")
    return regions[shard]


def group_name(recording: str, camera: str) -> str:
    """Group path of one recording and camera in the cache (`<recording>/<camera>`)."""
    return GROUP_TEMPLATE.format(recording=recording, camera=camera)


F16_MAX = 65504.0
"""Largest finite float16 (np.finfo(np.float16).max): latents and h are clipped to it."""


@dataclass(frozen=True)
class LatentNorm:
    """The latent normalization of a cache (root attribute `latent_norm`, by the stats stage).

    mean, std: per channel (C,); cells: latent cells it was computed over; groups: the valid
    views encoded in each `<recording>/<camera>` group it covers (its `views` the sum), so a
    cache whose groups or valid views changed since is told apart from the one it describes.
    """

    mean: list[float]
    std: list[float]
    cells: int
    groups: dict[str, int]

    @property
    def views(self) -> int:
        """Valid views the normalization was computed over."""
        return sum(self.groups.values())

    def to_attrs(self) -> dict[str, Any]:
        """The root attribute's value (`count`: cells, as readers of the first format read)."""
        return {"mean": self.mean, "std": self.std, "count": self.cells, "views": self.views,
                "groups": dict(sorted(self.groups.items()))}

    @classmethod
    def from_attrs(cls, raw: object) -> LatentNorm | None:
        """Parse the root attribute; None when absent or of a format without view counts."""
        if not isinstance(raw, dict) or not isinstance(raw.get("groups"), dict):
            return None
        return cls(list(raw["mean"]), list(raw["std"]), int(raw["count"]),
                   {str(k): int(v) for k, v in raw["groups"].items()})

    def stale_against(self, valid_views: dict[str, int | None]) -> str | None:
        """Why this normalization no longer describes the groups it covers, given the valid
        views each group of the cache holds now (group -> count, None for a group that is
        gone or unreadable), or None when it does."""
        for group, n in sorted(self.groups.items()):
            now = valid_views.get(group)
            if now != n:
                held = "is gone" if now is None else f"holds {now}"
                return (f"latent_norm was computed over {n} valid views of {group}, which now "
                        f"{held}")
        return None
