"""Parquet table schemas shared by writers and readers (stats, clips, run tables).

Each schema carries its kind and format version in the Arrow metadata;
`read_table` refuses a file whose version is unknown.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from schemas.atomic_io import record_checksum
from schemas.errors import DataError
from schemas.versioning import KIND_KEY, VERSION_KEY, check_version

TABLES_VERSION = 1
STATS_LAYOUT_VERSION = 2
"""How a table of several recordings is laid out on disk (`recording_part`): version 2, one
file per recording, `stats/<table>/<recording>.parquet`, whose `recording` column (a string)
is the only place the recording is named, so pandas, pyarrow, polars and DuckDB read the
folder with no option and agree on rows and types. Version 1 held hive folders
`recording=<rec>/` over files that also had the column: pyarrow (and pandas) refused to
merge the folder's dictionary type with the column's string type."""


def _versioned(kind: str, fields: list[pa.Field], version: int = TABLES_VERSION) -> pa.Schema:
    """Attach kind and version metadata (TABLES_VERSION unless the table has its own) to a
    list of fields."""
    meta = {KIND_KEY: kind, VERSION_KEY: str(version)}
    return pa.schema(fields, metadata=meta)


VIEW_STATS = _versioned(
    "view_stats",
    [
        pa.field("recording", pa.string(), nullable=False),
        pa.field("camera", pa.string(), nullable=False),
        pa.field("frame", pa.int64(), nullable=False),
        pa.field("stamp_ns", pa.int64(), nullable=False),
        pa.field("sweep_stamp_ns", pa.int64()),
        pa.field("dtau_s", pa.float64()),
        pa.field("supported_cells", pa.int32()),
        pa.field("points_in_frustum", pa.int64()),
        pa.field("points_too_near", pa.int64()),
        pa.field("depth_mean_m", pa.float64()),
        pa.field("depth_min_m", pa.float64()),
        pa.field("depth_max_m", pa.float64()),
        pa.field("reject_reason", pa.string()),
    ],
)

CELL_STATS = _versioned(
    "cell_stats",
    [
        pa.field("recording", pa.string(), nullable=False),
        pa.field("camera", pa.string(), nullable=False),
        pa.field("frame", pa.int64(), nullable=False),
        pa.field("row", pa.int16(), nullable=False),
        pa.field("col", pa.int16(), nullable=False),
        pa.field("n", pa.int64(), nullable=False),
        pa.field("depth_mean_m", pa.float64(), nullable=False),
        pa.field("depth_var_m2", pa.float64(), nullable=False),
    ],
)

CLIPS = _versioned(
    "clips",
    [
        pa.field("clip_id", pa.int64(), nullable=False),
        pa.field("split", pa.string(), nullable=False),
        pa.field("recording", pa.string(), nullable=False),
        pa.field("camera", pa.string(), nullable=False),
        pa.field("frames", pa.list_(pa.int64()), nullable=False),
        pa.field("is_target", pa.list_(pa.bool_()), nullable=False),
        pa.field("max_baseline_m", pa.float64(), nullable=False),
        pa.field("hard", pa.bool_(), nullable=False),
    ],
)

CLIPS_SPLIT_KEY = "m3gd_clips_split"
"""Schema metadata key of `clips.parquet`: how its clips were split, "recording" or "segment"
(`clips.split`); absent in a file written before the segment split (by recording)."""

ALIGNMENT = _versioned(
    "alignment",
    [
        pa.field("pair", pa.string(), nullable=False),
        pa.field("metric", pa.string(), nullable=False),
        pa.field("value", pa.float64(), nullable=False),
        pa.field("null_value", pa.float64(), nullable=False),
        pa.field("images", pa.int64(), nullable=False),
        pa.field("excluded_images", pa.int64(), nullable=False),
    ],
)

REPROJECTION_CONSISTENCY = _versioned(
    "reprojection_consistency",
    [
        pa.field("recording", pa.string(), nullable=False),
        pa.field("camera", pa.string(), nullable=False),
        pa.field("pairs", pa.int64(), nullable=False),  # view pairs behind the figures
        pa.field("points", pa.int64(), nullable=False),  # LiDAR points per pair (mean, rounded)
        pa.field("offset_ms", pa.float64(), nullable=False),  # camera clock minus LiDAR clock
        pa.field("roll_deg", pa.float64(), nullable=False),  # about the optical axis z
        pa.field("pitch_deg", pa.float64(), nullable=False),  # about x (right)
        pa.field("yaw_deg", pa.float64(), nullable=False),  # about y (down)
        pa.field("rotation_deg", pa.float64(), nullable=False),  # angle of the rotation
        pa.field("rotation_method", pa.string(), nullable=False),  # "lidar_edges"
        pa.field("edge_views", pa.int64(), nullable=False),  # views behind the rotation
        pa.field("edge_points", pa.int64(), nullable=False),  # LiDAR edge points in them
        pa.field("edge_score_before", pa.float64(), nullable=False),  # edge alignment, recorded
        pa.field("edge_score_after", pa.float64(), nullable=False),  # at the recovered rotation
        pa.field("error_before", pa.float64(), nullable=False),  # grey levels^2, at recorded
        pa.field("error_after", pa.float64(), nullable=False),  # at the recovered (offset, rot)
    ],
    version=2,
)
"""Version 2: the rotation from LiDAR edge alignment (rotation_method, edge_* columns); the
pair errors give the clock offset only."""

ACCURACY = _versioned(
    "accuracy",
    [
        pa.field("recording", pa.string(), nullable=False),
        pa.field("camera", pa.string(), nullable=False),
        pa.field("frame", pa.int64(), nullable=False),
        pa.field("row", pa.int16(), nullable=False),
        pa.field("col", pa.int16(), nullable=False),
        pa.field("border", pa.bool_(), nullable=False),
        pa.field("depth_m", pa.float64(), nullable=False),
        pa.field("gt_depth_m", pa.float64()),
        pa.field("gt_spread_m", pa.float64()),
        pa.field("abs_rel", pa.float64()),
        pa.field("dtau_s", pa.float64(), nullable=False),
        pa.field("speed_mps", pa.float64()),
        pa.field("yaw_rate_rps", pa.float64()),
    ],
)
"""One row per occupied packet cell of an accepted view: packet mean depth against the
ground-truth median depth of the cell's pixels (null where the cell has no reference surface),
border flag (depth discontinuity in the cell), the view's Δτ and the robot's ground-truth speed
and yaw rate at the image's capture time (null outside the ground-truth poses; see
packets.accuracy)."""

EVAL_TARGETS_VERSION = 1


def eval_targets_schema(baselines: tuple[str, ...], candidates: tuple[str, ...]) -> pa.Schema:
    """The per-target table of `m3gd eval` (`<eval>.parquet`): clip, view, hard flag, the
    model's PSNR / SSIM, `psnr_<b>` / `ssim_<b>` of every baseline b (null where a target has
    none), the reprojection consistency `reproj_err` (the model) and `reproj_err_<c>` of every
    other candidate c (null where the target has no reprojection) and its points. Every
    column is typed whatever the targets hold, so every reader agrees on the types."""
    fields = [pa.field("clip_id", pa.int64(), nullable=False),
              pa.field("view", pa.int64(), nullable=False),
              pa.field("hard", pa.bool_(), nullable=False),
              pa.field("psnr", pa.float64(), nullable=False),
              pa.field("ssim", pa.float64(), nullable=False)]
    fields += [pa.field(f"{k}_{b}", pa.float64()) for b in baselines for k in ("psnr", "ssim")]
    fields += [pa.field("reproj_err" if c == "model" else f"reproj_err_{c}", pa.float64())
               for c in candidates]
    fields.append(pa.field("reproj_points", pa.int64(), nullable=False))
    return _versioned("eval_targets", fields, version=EVAL_TARGETS_VERSION)


ALL_TABLES: dict[str, pa.Schema] = {
    "view_stats": VIEW_STATS,
    "cell_stats": CELL_STATS,
    "clips": CLIPS,
    "alignment": ALIGNMENT,
    "accuracy": ACCURACY,
    "reprojection_consistency": REPROJECTION_CONSISTENCY,
}


QUERYABLE: dict[str, str] = {
    "view_stats": "one row per view (Δτ, supported cells, depths, reject reason); `m3gd run`",
    "cell_stats": "one row per occupied packet cell (n, depth mean and variance); `m3gd run`",
    "clips": "the train / eval clip index; `m3gd run`",
    "alignment": "2D-3D alignment figures beside their permutation nulls; `m3gd align`",
    "accuracy": "packet cell depth against ground truth, per cell; `m3gd accuracy`",
    "reprojection_consistency": "per camera, the clock offset and extrinsic rotation that make "
    "its views agree on the LiDAR points, errors before / after; `m3gd align --consistency`",
}
"""The statistics tables `m3gd stats query` can read, with what a row is and the command that
writes it."""

INDEX_QUERYABLE: dict[str, str] = {
    "images": "one row per camera image kept (camera, frame, stamp, file, topic); `m3gd run`",
    "sweeps": "one row per LiDAR sweep kept (stamp, points by kind); `m3gd run`",
    "odometry": "one row per odometry sample (stamp, position, orientation); `m3gd run`",
    "calibration": "one row per sensor (extrinsics, intrinsics); `m3gd run`",
    "rejects": "one row per rejected message or problem (file, topic, stamp, reason); `m3gd run`",
    "damage": "one row per unreadable byte range of a bag; `m3gd run`",
    "accounting": "messages read, kept and rejected per file and topic; `m3gd run`",
    "checks": "plausibility checks per topic (state, messages flagged); `m3gd run`",
    "selection": "one row per selected view (camera, frame, sweep, Δτ); `m3gd run`",
}
"""The recording index tables `m3gd stats query` can read (one file per recording under
`index/<recording>/`, the folder giving the `recording` column)."""


def recording_part(folder: Path, recording: str) -> Path:
    """The file of one recording in a per-recording table folder (`STATS_LAYOUT_VERSION`)."""
    return folder / f"{recording}.parquet"


def write_recording_part(table: pa.Table, schema: pa.Schema, folder: Path,
                         recording: str) -> Path:
    """Write one recording's rows of a per-recording table (`recording_part`) and remove the
    `recording=<rec>/` folder of layout version 1 where one is left; returns the file."""
    path = recording_part(folder, recording)
    write_table(table, schema, path)
    old = folder / f"recording={recording}"
    if old.is_dir():
        shutil.rmtree(old)
    return path


def write_table(table: pa.Table, schema: pa.Schema, path: Path) -> None:
    """Write `table` cast to `schema` (metadata included) atomically to `path`."""
    table = table.select(schema.names).cast(schema)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    pq.write_table(table, tmp)
    tmp.replace(path)
    record_checksum(path)


def check_schema(schema: pa.Schema, expected: pa.Schema, where: str) -> None:
    """Refuse a file whose kind or version differs from `expected`."""
    meta = schema.metadata or {}
    kind = (expected.metadata or {}).get(KIND_KEY.encode(), b"").decode()
    found_kind = meta.get(KIND_KEY.encode(), b"").decode()
    if found_kind != kind:
        raise DataError(f"{where}: expected a {kind!r} table, found {found_kind or 'unknown'!r}")
    want = int((expected.metadata or {}).get(VERSION_KEY.encode(), str(TABLES_VERSION)))
    check_version(meta.get(VERSION_KEY.encode(), b"").decode(), want, kind, where)


def read_table(path: Path, expected: pa.Schema) -> pa.Table:
    """Read a Parquet file written with `expected`; refuse unknown versions."""
    return read_checked(path, expected, check_schema)


def read_checked(path: Path, expected: pa.Schema,
                 check: Callable[[pa.Schema, pa.Schema, str], None]) -> pa.Table:
    """Read `path` as `expected` once `check(found, expected, where)` accepts its schema.

    A file Arrow cannot parse (truncated, not Parquet) is a DataError naming it.
    """
    try:
        schema = pq.read_schema(path)
        check(schema, expected, str(path))
        return pq.read_table(path, schema=expected)
    except pa.ArrowInvalid as err:
        raise DataError(f"{path}: not a readable Parquet file: {err}") from err
