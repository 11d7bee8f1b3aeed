"""What an inspection found, as plain frozen records (JSON through `as_dict`).

Times are int64 ns (log times from the bag indexes, header stamps from messages); rates in Hz;
durations and gaps in seconds (float, for reading).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass(frozen=True)
class Gap:
    """A pause in a topic: `start_ns` is the log time of the message before it, `seconds` its
    length (the interval to the next message)."""

    start_ns: int
    seconds: float


@dataclass(frozen=True)
class TopicStats:
    """One topic over the whole recording, from the indexes.

    count: messages; first_ns/last_ns: first and last log time (None when the index gives no
    times); rate_hz: (count - 1) / (last - first); period_s: median interval between
    messages; gaps: intervals longer than `GAP_FACTOR` median periods, longest first (at most
    `MAX_GAPS`), `n_gaps` all of them; files: the bags holding it.
    """

    topic: str
    msgtype: str
    count: int
    first_ns: int | None = None
    last_ns: int | None = None
    rate_hz: float | None = None
    period_s: float | None = None
    n_gaps: int = 0
    gaps: tuple[Gap, ...] = ()
    files: tuple[str, ...] = ()


@dataclass(frozen=True)
class TfEdge:
    """A transform parent -> child as written (T_parent_child): on a static topic or not,
    in how many of the sampled messages. A dynamic edge's motion over the sampled messages:
    rate_hz from its header stamps (None: fewer than two), travel_m the path length of its
    translation (m), jump_m the longest single step of it (m)."""

    parent: str
    child: str
    static: bool
    topic: str
    messages: int
    rate_hz: float | None = None
    travel_m: float = 0.0
    jump_m: float = 0.0


@dataclass(frozen=True)
class TfReport:
    """The TF tree: edges as written, root frames (never a child), frames with more than one
    parent (a broken tree), and how many dynamic messages were sampled per topic."""

    edges: tuple[TfEdge, ...] = ()
    roots: tuple[str, ...] = ()
    frames: tuple[str, ...] = ()
    multiple_parents: dict[str, list[str]] = field(default_factory=dict)
    sampled: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class PointField:
    """One field of a point: name, PointField datatype code and numpy dtype, byte offset,
    count."""

    name: str
    datatype: int
    dtype: str
    offset: int
    count: int


@dataclass(frozen=True)
class SweepTime:
    """Point-time evidence of one sampled sweep.

    header_ns: header stamp; raw_min/raw_max: the time field's finite values as float64 in
    the field's own unit (None without a time field or finite value); n_nonfinite: points
    whose time is NaN or Inf; read_first_ns/read_last_ns: the kept points' first and last
    time as the reader turns the field into ns (`pipeline.ingest.sources.pointcloud`), and
    `read_corrupt`: points with a corrupt coordinate (a time never makes one); points: width x
    height.
    """

    header_ns: int
    log_ns: int
    points: int
    raw_min: float | None
    raw_max: float | None
    n_nonfinite: int
    read_first_ns: int
    read_last_ns: int
    read_corrupt: int


@dataclass(frozen=True)
class UnitReading:
    """The sampled time values read in one unit: span within a sweep (s, median over the
    sweeps) and the first point's offset from the header stamp (s, median) read as absolute
    time and as time relative to the header stamp."""

    unit: str
    span_s: float
    offset_if_absolute_s: float
    offset_if_relative_s: float


@dataclass(frozen=True)
class Convention:
    """How point times are read: `decided_by` says by what; unit and reference as decided
    (None: the header stamp for every point)."""

    decided_by: str
    unit: str | None
    reference: str | None
    note: str = ""


@dataclass(frozen=True)
class CloudReport:
    """One PointCloud2 topic: frame, layout and point-time evidence from its first messages.

    sweep_period_s: median interval of the sampled header stamps; time_field/time_dtype: the
    per-point time field the reader would use (None: none); units: the evidence read in each
    unit; convention: `clouds.decide_convention` of it.
    """

    topic: str
    frame_id: str
    fields: tuple[PointField, ...]
    point_step: int
    row_step: int
    width: int
    height: int
    is_dense: bool
    is_bigendian: bool
    time_field: str | None
    time_dtype: str | None
    sweeps: tuple[SweepTime, ...]
    sweep_period_s: float | None
    units: tuple[UnitReading, ...]
    convention: Convention
    error: str | None = None


@dataclass(frozen=True)
class Calibration:
    """One sampled CameraInfo (or the HF `camera_info` attribute): where, model, size, K."""

    stamp_ns: int
    distortion_model: str
    n_coefficients: int
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float


@dataclass(frozen=True)
class CameraReport:
    """One camera topic: image topic and type, info topic, frame, encoding or format, the
    size of the sampled images, the sampled calibrations and whether they change."""

    image_topic: str
    image_type: str
    info_topic: str | None
    frame_id: str
    encoding: str
    image_sizes: tuple[tuple[int, int], ...]
    calibrations: tuple[Calibration, ...]
    calibration_changes: bool
    error: str | None = None
    info_frame_id: str = ""


@dataclass(frozen=True)
class Agreement:
    """An odometry topic against the /tf edge between the same two frames, over the stamps
    both carry (within 5 ms): `error_m` the largest difference (m) of the body's motion from
    the first common stamp, as each source gives it (frame-independent: relative motion),
    `travel_m` the longest such motion; `samples` stamps compared."""

    topic: str
    edge: str
    samples: int
    error_m: float
    travel_m: float


@dataclass(frozen=True)
class Candidate:
    """One option of a decision: a name (an edge `parent->child`, a topic, a frame), the
    configuration keys it implies, its evidence in short phrases, and its score (higher:
    better; only the order matters); `usable`: False for one the evidence rules out (a LiDAR
    topic without messages)."""

    name: str
    keys: dict[str, Any]
    evidence: tuple[str, ...]
    score: float
    usable: bool = True


@dataclass(frozen=True)
class Decision:
    """What inspect decided about one part of the rig (`what`: pose, lidar, camera <topic>):
    the chosen candidate's name ('' when none fits), every candidate with its evidence (the
    chosen first), whether the evidence left it `ambiguous`, and why, in one line."""

    what: str
    chosen: str
    candidates: tuple[Candidate, ...]
    ambiguous: bool
    reason: str

    @property
    def keys(self) -> dict[str, Any]:
        """The chosen candidate's configuration keys ({} when none)."""
        return next((c.keys for c in self.candidates if c.name == self.chosen), {})

    def line(self) -> str:
        """The decision in one line: `what: chosen (ambiguous: ...)` or with its reason."""
        flag = "AMBIGUOUS, " if self.ambiguous else ""
        return f"{self.what}: {self.chosen or '(none)'} ({flag}{self.reason})"


@dataclass(frozen=True)
class Inspection:
    """Everything `m3gd inspect` reports about one recording.

    path: what was inspected; format: rosbag1, rosbag2 or hf-zarr; files: bags (or the store)
    with sizes in bytes; odometry: (topic, frame_id, child_frame_id) of every odometry
    topic's first message (nav_msgs/Odometry, then the pose types of `tf_odometry.POSE_TYPES`,
    whose child is ''); notes: what could not be read, in one line each; agreement: odometry
    topics against /tf; decisions: the pose source, LiDARs and camera frames inspect chose
    (`pipeline.inspect.decide`), with their alternatives and evidence.
    """

    path: str
    format: str
    files: dict[str, int]
    topics: tuple[TopicStats, ...]
    tf: TfReport
    clouds: tuple[CloudReport, ...]
    cameras: tuple[CameraReport, ...]
    odometry: tuple[tuple[str, str, str], ...] = ()
    notes: tuple[str, ...] = ()
    seconds: float = 0.0
    agreement: tuple[Agreement, ...] = ()
    decisions: tuple[Decision, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-compatible data."""
        return asdict(self)

    @property
    def bytes(self) -> int:
        """Total size of the files read."""
        return sum(self.files.values())
