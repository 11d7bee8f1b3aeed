"""The recording index (ingest output) and the view selection (select output) as Parquet schemas.

Layout: `<out_dir>/index/<recording>/{images,sweeps,odometry,calibration,rejects,damage,
accounting}.parquet`, and
`selection.parquet` beside them once selected. Every schema carries its kind and the format
version in the Arrow metadata; `read_index_table` refuses an unknown version with a clear error.
Stamps are int64 nanoseconds; transforms are row-major 4x4 float64 (`T_a_b` maps b into a);
`K` are row-major 3x3 float64.
"""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from schemas.atomic_io import record_checksum
from schemas.errors import DataError, MissingInputError
from schemas.layout import OutputLayout
from schemas.tables import read_checked
from schemas.versioning import KIND_KEY, VERSION_KEY, check_version

INDEX_VERSION = 1
SWEEPS_VERSION = 4
"""The sweeps table's format version (its own: the other index tables are at INDEX_VERSION)."""
SELECTION_FILE = "selection.parquet"
SELECTION_LIDARS_FILE = "selection_lidars.parquet"


class Reason(StrEnum):
    """Reason codes of the rejects table (and of rejected views in the selection).

    Most rows drop a message; `stream_gap` (a topic silent for longer than its rate allows),
    `missing_tf_edge` (for a sensor skipped anyway) and `damaged_region` (bytes of a bag that
    could not be read; its messages were never read, see the damage table) record a problem
    without dropping a message that was read. `MESSAGE_REASONS` are the reasons that drop one
    message that was read; `nonfinite_points` is one of them (a sweep with a point no sensor
    produces: a coordinate beyond 1e5 m or a broken point time; invalid returns, NaN/Inf in a
    coordinate, are counted by kind in the sweeps table, not rejected). `missing_file`: a row
    of a Hugging Face store whose JPEG file is absent. `unsupported_image`: an intact camera
    message of an encoding m3gd does not read (not damage); `calibration_mismatch`: an image
    that does not fit its own CameraInfo (the latest at or before its stamp: another size, or
    an unusable calibration).
    """

    TRUNCATED_BAG = "truncated_bag"
    UNREADABLE_BAG = "unreadable_bag"
    UNDECODABLE_MESSAGE = "undecodable_message"
    CORRUPT_JPEG = "corrupt_jpeg"
    MISSING_CAMERA_INFO = "missing_camera_info"
    DUPLICATE_STAMP = "duplicate_stamp"
    OUT_OF_ORDER_STAMP = "out_of_order_stamp"
    EMPTY_SWEEP = "empty_sweep"
    BAD_POINTCLOUD = "bad_pointcloud"
    ODOM_GAP = "odom_gap"
    DTAU_EXCEEDED = "dtau_exceeded"
    NO_SWEEP = "no_sweep"
    MISSING_TOPIC = "missing_topic"
    MISSING_TF_EDGE = "missing_tf_edge"
    STREAM_GAP = "stream_gap"
    NONFINITE_POINTS = "nonfinite_points"
    MISSING_FILE = "missing_file"
    DAMAGED_REGION = "damaged_region"
    BAD_CAMERA_INFO = "bad_camera_info"
    BAD_POSE = "bad_pose"
    UNSUPPORTED_IMAGE = "unsupported_image"
    CALIBRATION_MISMATCH = "calibration_mismatch"


MESSAGE_REASONS = frozenset({
    Reason.UNDECODABLE_MESSAGE, Reason.CORRUPT_JPEG, Reason.DUPLICATE_STAMP,
    Reason.OUT_OF_ORDER_STAMP, Reason.EMPTY_SWEEP, Reason.BAD_POINTCLOUD, Reason.BAD_POSE,
    Reason.NONFINITE_POINTS, Reason.UNSUPPORTED_IMAGE, Reason.CALIBRATION_MISMATCH,
})
"""Reject reasons that drop exactly one message that was read (the accounting counts them)."""


class ViewStatus(StrEnum):
    """Outcome of selection for one view."""

    OK = "ok"
    REJECTED = "rejected"


def _versioned(kind: str, fields: list[pa.Field], version: int = INDEX_VERSION) -> pa.Schema:
    """Attach kind and format-version metadata to a list of fields."""
    return pa.schema(fields, metadata={KIND_KEY: kind, VERSION_KEY: str(version)})


def _mat(name: str, n: int) -> pa.Field:
    """A fixed-size float64 list field (a flattened row-major matrix of n entries)."""
    return pa.field(name, pa.list_(pa.float64(), n), nullable=False)


_WHERE = [
    pa.field("file", pa.string(), nullable=False),
    pa.field("topic", pa.string(), nullable=False),
    pa.field("bag_time_ns", pa.int64(), nullable=False),
    pa.field("ordinal", pa.int64(), nullable=False),
]
"""Where a message lives: bag file (relative to the mission folder), topic, log time and the
message's 0-based position among the topic's messages in that file, in reading order."""

IMAGES = _versioned(
    "index_images",
    [
        pa.field("camera", pa.string(), nullable=False),
        pa.field("frame", pa.int64(), nullable=False),
        pa.field("stamp_ns", pa.int64(), nullable=False),
        *_WHERE,
        pa.field("jpeg_bytes", pa.int64(), nullable=False),
    ],
)

SWEEPS = _versioned(
    "index_sweeps",
    [
        pa.field("sweep", pa.int64(), nullable=False),
        pa.field("lidar", pa.string(), nullable=False),
        pa.field("stamp_ns", pa.int64(), nullable=False),
        *_WHERE,
        pa.field("n_points", pa.int64(), nullable=False),
        pa.field("n_valid", pa.int64(), nullable=False),
        pa.field("n_nonfinite", pa.int64(), nullable=False),
        pa.field("n_nan", pa.int64(), nullable=False),
        pa.field("n_posinf", pa.int64(), nullable=False),
        pa.field("n_neginf", pa.int64(), nullable=False),
        pa.field("n_zero", pa.int64(), nullable=False),
        pa.field("t_first_ns", pa.int64(), nullable=False),
        pa.field("t_last_ns", pa.int64(), nullable=False),
        pa.field("time_field", pa.string(), nullable=False),
        pa.field("time_unit", pa.string(), nullable=False),
        pa.field("time_reference", pa.string(), nullable=False),
    ],
    version=SWEEPS_VERSION,
)
"""One row per kept sweep. Points by kind: n_points in the message = n_valid (kept) +
n_nonfinite (invalid returns: n_nan + n_posinf + n_neginf, a point counted by the first of NaN,
+Inf, -Inf among its coordinates) + n_zero (all-zero points). Version 2 added n_nan, n_posinf,
n_neginf. t_first_ns, t_last_ns: the earliest and latest kept point's time under the topic's
point-time convention, named by time_field, time_unit (s, ms, us, ns) and time_reference
(absolute, header, first_point; `schemas.time_conventions`), all "" when the points take the
header stamp. Version 3 added the time_* columns; version 4 the `lidar` column (the sweep's
LiDAR, a name of `ingest.topics.lidars`, else "lidar"; `sweep` numbers all LiDARs' sweeps
together, each LiDAR's stamps increasing)."""

CHECKS = _versioned(
    "index_checks",
    [
        pa.field("topic", pa.string(), nullable=False),
        pa.field("check", pa.string(), nullable=False),
        pa.field("state", pa.string(), nullable=False),
        pa.field("messages", pa.int64(), nullable=False),
        pa.field("flagged", pa.int64(), nullable=False),
        pa.field("rejected", pa.int64(), nullable=False),
        pa.field("trusted", pa.int64(), nullable=False),
        pa.field("detail", pa.string(), nullable=False),
    ],
)
"""One row per plausibility check and topic it ran on: its state at the end of the stream
(`on`; `off`: its model did not fit the first messages; `capped`: it stopped rejecting at the
configured share), the messages it judged, those it found implausible (`flagged`) and those it
rejected, those it did not judge because a verified chunk checksum vouches for their bytes
(`trusted`); `detail`: the measured misfit or the first problem, one line."""

ODOMETRY = _versioned(
    "index_odometry",
    [
        pa.field("stamp_ns", pa.int64(), nullable=False),
        pa.field("frame_id", pa.string(), nullable=False),
        pa.field("child_frame_id", pa.string(), nullable=False),
        pa.field("position", pa.list_(pa.float64(), 3), nullable=False),
        pa.field("quat_xyzw", pa.list_(pa.float64(), 4), nullable=False),
    ],
)

CALIBRATION = _versioned(
    "index_calibration",
    [
        pa.field("sensor", pa.string(), nullable=False),
        pa.field("frame_id", pa.string(), nullable=False),
        pa.field("kind", pa.string(), nullable=False),
        _mat("T_base_sensor", 16),
        pa.field("model", pa.string()),
        pa.field("width", pa.int32()),
        pa.field("height", pa.int32()),
        pa.field("K", pa.list_(pa.float64(), 9)),
        pa.field("D", pa.list_(pa.float64())),
        pa.field("out_width", pa.int32()),
        pa.field("out_height", pa.int32()),
        pa.field("K_out", pa.list_(pa.float64(), 9)),
        pa.field("decode_reduction", pa.int32()),
    ],
)
"""One row per sensor: cameras (kind 'camera', with raw and output intrinsics), the LiDAR
(kind 'lidar') and the odometry body (kind 'base', identity)."""

REJECTS = _versioned(
    "index_rejects",
    [
        pa.field("file", pa.string(), nullable=False),
        pa.field("topic", pa.string(), nullable=False),
        pa.field("stamp_ns", pa.int64(), nullable=False),
        pa.field("reason", pa.string(), nullable=False),
        pa.field("detail", pa.string(), nullable=False),
    ],
)

DAMAGE = _versioned(
    "index_damage",
    [
        pa.field("file", pa.string(), nullable=False),
        pa.field("byte_start", pa.int64(), nullable=False),
        pa.field("byte_end", pa.int64(), nullable=False),
        pa.field("topics", pa.list_(pa.string()), nullable=False),
        pa.field("first_ns", pa.int64(), nullable=False),
        pa.field("last_ns", pa.int64(), nullable=False),
        pa.field("messages", pa.int64(), nullable=False),
        pa.field("cause", pa.string(), nullable=False),
    ],
)
"""One row per unreadable byte range of a bag: the topics and log times it could have held, and
its message count per the chunk index (-1 when a forward scan found it)."""

ACCOUNTING = _versioned(
    "index_accounting",
    [
        pa.field("file", pa.string(), nullable=False),
        pa.field("topic", pa.string(), nullable=False),
        pa.field("read", pa.int64(), nullable=False),
        pa.field("kept", pa.int64(), nullable=False),
        pa.field("rejected", pa.int64(), nullable=False),
    ],
)
"""Per bag file and streamed topic: messages read = kept (index rows) + rejected (reject rows)."""

_VIEW_ID = [pa.field("camera", pa.string(), nullable=False),
            pa.field("frame", pa.int64(), nullable=False)]
_SWEEP_CHOICE = [pa.field("sweep", pa.int64(), nullable=False),
                 pa.field("sweep_stamp_ns", pa.int64(), nullable=False),
                 pa.field("dtau_s", pa.float64(), nullable=False),
                 _mat("T_cam_lidar", 16)]
"""A view's nearest sweep of one LiDAR: its id, stamp (ns), delta tau (s), T_cam_lidar."""
_VERDICT = [pa.field("status", pa.string(), nullable=False),
            pa.field("reason", pa.string(), nullable=False)]

SELECTION = _versioned(
    "selection",
    [*_VIEW_ID, pa.field("stamp_ns", pa.int64(), nullable=False), *_SWEEP_CHOICE,
     _mat("T_world_cam", 16), _mat("K_out", 9), *_VERDICT],
)
"""One row per view. Rejected views keep their row (status 'rejected', a reason code); their
sweep is -1 when none exists and their transforms are identity."""

SELECTION_LIDARS = _versioned(
    "selection_lidars",
    [*_VIEW_ID, pa.field("lidar", pa.string(), nullable=False), *_SWEEP_CHOICE, *_VERDICT],
)
"""Written only when `select.lidar` merges several LiDARs: one row per view and merged LiDAR
(the reference first), each with that LiDAR's nearest sweep, its delta tau (s) and its
camera-from-LiDAR transform through the sweep's own pose; a LiDAR row is rejected (status,
reason) on the same rules as a view, and a rejected row adds no points to the packet."""

GEOMETRY = _versioned(
    "index_geometry",
    [
        pa.field("camera", pa.string(), nullable=False),
        pa.field("verdict", pa.string(), nullable=False),
        pa.field("reason", pa.string(), nullable=False),
        pa.field("cause", pa.string(), nullable=False),
        pa.field("accepted", pa.bool_(), nullable=False),
        pa.field("views", pa.int64(), nullable=False),
        pa.field("edge_points", pa.int64(), nullable=False),
        pa.field("score", pa.float64(), nullable=True),
        pa.field("null_mean", pa.float64(), nullable=True),
        pa.field("null_std", pa.float64(), nullable=True),
        pa.field("z", pa.float64(), nullable=True),
        pa.field("p_value", pa.float64(), nullable=True),
        pa.field("wins", pa.float64(), nullable=True),
        pa.field("best_score", pa.float64(), nullable=True),
        pa.field("best_moved", pa.string(), nullable=False),
    ],
)
"""One row per camera: the geometry verdict written after the packets stage
(`packets.geometry_verdict`, `pipeline.analysis.geometry_check`): `ok`, `inconclusive` or
`failed`, the reason and likely cause in one line each, whether the user accepted a failure
(`geometry.accept`, `--accept-geometry`); the views and LiDAR edge points scored, the mean
LiDAR-edge score of the real pairs (`score`), its shuffled-pairs null (mean, std), z, the tail
probability, the share of views beating their null median (`wins`), the best score a small
search of rotation and clock offset reached and what it moved; null where not computed."""

INDEX_TABLES: dict[str, pa.Schema] = {
    "images": IMAGES,
    "sweeps": SWEEPS,
    "odometry": ODOMETRY,
    "calibration": CALIBRATION,
    "rejects": REJECTS,
    "damage": DAMAGE,
    "accounting": ACCOUNTING,
    "checks": CHECKS,
    "geometry": GEOMETRY,
}


def index_dir(out_dir: Path, recording: str) -> Path:
    """Folder of one recording's index under an output directory."""
    return OutputLayout(out_dir).index_of(recording)


def table_path(idx_dir: Path, name: str) -> Path:
    """Path of index table `name` (a key of INDEX_TABLES, or 'selection')."""
    return idx_dir / (SELECTION_FILE if name == "selection" else f"{name}.parquet")


def _kind(schema: pa.Schema) -> str:
    """The kind string stored in a schema's metadata ('' if absent)."""
    raw: bytes = (schema.metadata or {}).get(KIND_KEY.encode(), b"")
    return raw.decode()


def check_index_schema(found: pa.Schema, expected: pa.Schema, where: str) -> None:
    """Refuse a file of another kind or an unknown format version, naming the file."""
    kind = _kind(expected)
    if _kind(found) != kind:
        raise DataError(f"{where}: expected a {kind!r} table, found {_kind(found) or 'unknown'!r}")
    meta = found.metadata or {}
    known = int((expected.metadata or {}).get(VERSION_KEY.encode(), str(INDEX_VERSION).encode()))
    check_version(meta.get(VERSION_KEY.encode(), b"").decode(), known, kind, where)


def read_index_table(path: Path, expected: pa.Schema) -> pa.Table:
    """Read one index table; refuse a missing file, another kind or an unknown version."""
    if not path.exists():
        raise MissingInputError(f"{path}: index table not found (run ingest first)")
    return read_checked(path, expected, check_index_schema)


def write_index_table(table: pa.Table, schema: pa.Schema, path: Path) -> None:
    """Write `table` cast to `schema` (metadata included) atomically to `path`."""
    table = table.select(schema.names).cast(schema)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    pq.write_table(table, tmp)
    tmp.replace(path)
    record_checksum(path)


class IndexTableWriter:
    """Streams record batches of one index table to Parquet (flat memory), atomically on close."""

    def __init__(self, path: Path, schema: pa.Schema, batch_rows: int = 4096) -> None:
        """Open a temp file beside `path`; rows are flushed every `batch_rows`."""
        self.path = path
        self.schema = schema
        self.batch_rows = batch_rows
        self.rows: list[dict[str, object]] = []
        self.count = 0
        path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = path.with_name(f".{path.name}.tmp")
        self._writer = pq.ParquetWriter(self._tmp, schema)

    def append(self, row: dict[str, object]) -> None:
        """Add one row (a mapping of every field name to its value)."""
        self.rows.append(row)
        self.count += 1
        if len(self.rows) >= self.batch_rows:
            self.flush()

    def flush(self) -> None:
        """Write the buffered rows as one row group."""
        if self.rows:
            self._writer.write_table(pa.Table.from_pylist(self.rows, schema=self.schema))
            self.rows = []

    def close(self) -> None:
        """Flush, close and move the file into place."""
        self.flush()
        self._writer.close()
        self._tmp.replace(self.path)
        record_checksum(self.path)

    def abort(self) -> None:
        """Close and delete the temp file (after an error)."""
        self._writer.close()
        self._tmp.unlink(missing_ok=True)
