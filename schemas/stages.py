"""The stage table: every stage of the m3gd graph declared once, as data.

One row per stage, in the order the graph runs them: its name, the stages it depends on, the
granularity of its items (and the unit its progress counts), the config sections its cache
key hashes, the cache arrays, root attributes and tables it writes, and the check the run
makes after it. No row holds a function: `dags.graph` binds each row to its plan and run
functions; the verify redo (`pipeline.cache.verify`), the checksum owners
(`pipeline.run.checksums`), the report's stage order, the empty-recording check of the run
policy and the arrays' writers (`schemas.cache_layout`) read this table. Adding a stage is
one row here and one binding there.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

LATENT_PREFIX = "latents_l"
"""Latent arrays are named `latents_l<level>` (the encode stage's arrays)."""


class Granularity(StrEnum):
    """What one item of a stage covers: a synthetic scene, a recording, one camera's shard
    of a recording (its done-marks cover that shard), or the whole output (a cross item).
    A stage with `RECORDING` items may also have one cross item (`StageSpec.cross`)."""

    SCENE = "scene"
    RECORDING = "recording"
    SHARD = "shard"
    CROSS = "cross"


class PostCheck(StrEnum):
    """A check the run makes on a stage's outputs once the stage ran."""

    EMPTY_RECORDINGS = "empty_recordings"
    """Recordings whose selection accepted no view (`pipeline.run.outcome`)."""
    GEOMETRY_VERDICT = "geometry_verdict"
    """Cameras whose geometry verdict failed (`pipeline.analysis.geometry_check`)."""


@dataclass(frozen=True)
class StageSpec:
    """One stage of the graph, declared (module doc).

    depends: names of the stages it reads from; items: its item granularity; cross: whether
    it also has one cross-recording item; unit: what its progress counts; key_sections: the
    config sections its cache key hashes (besides its inputs' identities), in key order;
    arrays: cache arrays it writes in every `<recording>/<camera>` group (latents: their
    name prefix); root_attrs: attributes of the cache root it writes; tables: index tables
    (`index/<recording>/<name>.parquet`) and statistics tables it writes; check: what the
    run checks after it (None: nothing).
    """

    name: str
    depends: tuple[str, ...]
    items: Granularity
    unit: str
    key_sections: tuple[str, ...] = ()
    arrays: tuple[str, ...] = ()
    root_attrs: tuple[str, ...] = ()
    tables: tuple[str, ...] = ()
    check: PostCheck | None = None
    cross: bool = False


SYNTH = StageSpec("synth", (), Granularity.SCENE, "recordings", ("synth",))
INGEST = StageSpec(
    "ingest", (SYNTH.name,), Granularity.RECORDING, "images", ("ingest", "cache"),
    arrays=("images", "stamp_ns", "K"),
    tables=("images", "sweeps", "odometry", "calibration", "rejects", "damage", "accounting",
            "checks"))
SELECT = StageSpec(
    "select", (INGEST.name,), Granularity.RECORDING, "views", ("ingest", "select", "cache"),
    arrays=("sweep_stamp_ns", "dtau_s", "T_world_cam", "T_cam_lidar", "valid"),
    tables=("selection", "selection_lidars"), check=PostCheck.EMPTY_RECORDINGS)
ENCODE = StageSpec(
    "encode", (SELECT.name,), Granularity.SHARD, "views",
    ("encoders", "cache", "ingest", "select"), arrays=(LATENT_PREFIX,))
PACKETS = StageSpec(
    "packets", (SELECT.name,), Granularity.SHARD, "views",
    ("packets", "encoders", "ingest", "select", "cache"), arrays=("g", "h_cells"))
GEOMETRY = StageSpec(
    "geometry", (PACKETS.name,), Granularity.RECORDING, "cameras",
    ("geometry", "packets", "encoders"), tables=("geometry",),
    check=PostCheck.GEOMETRY_VERDICT)
STATS = StageSpec(
    "stats", (ENCODE.name, PACKETS.name), Granularity.RECORDING, "rows",
    ("ingest", "select", "encoders", "packets", "cache"), root_attrs=("latent_norm",),
    tables=("view_stats", "cell_stats"), cross=True)
CLIPS = StageSpec(
    "clips", (STATS.name,), Granularity.CROSS, "clips",
    ("ingest", "select", "encoders", "packets", "cache", "clips"), tables=("clips",))

STAGE_TABLE: tuple[StageSpec, ...] = (SYNTH, INGEST, SELECT, ENCODE, PACKETS, GEOMETRY, STATS,
                                      CLIPS)
"""Every stage, in the order the graph runs them."""

STAGE_ORDER: tuple[str, ...] = tuple(s.name for s in STAGE_TABLE)
"""The stage names in graph order."""


def stage_spec(name: str) -> StageSpec | None:
    """The row of stage `name`, None for a name the table does not hold."""
    return next((s for s in STAGE_TABLE if s.name == name), None)


def writes_array(spec: StageSpec, array: str) -> bool:
    """Whether `spec` writes cache array `array` (LATENT_PREFIX stands for the names it
    prefixes to a level number: `latents_l0`, `latents_l1`, ...)."""
    for name in spec.arrays:
        if name == LATENT_PREFIX:
            if array.startswith(name) and array[len(name):].isdigit():
                return True
        elif name == array:
            return True
    return False


def writer_of_array(array: str) -> StageSpec | None:
    """The stage that writes cache array `array`; None for one no stage declares."""
    return next((s for s in STAGE_TABLE if writes_array(s, array)), None)


def writer_of_table(table: str) -> StageSpec | None:
    """The stage that writes table `table` (an index or statistics table name)."""
    return next((s for s in STAGE_TABLE if table in s.tables), None)


def writer_of_root_attr(attr: str) -> StageSpec | None:
    """The stage that writes attribute `attr` of the cache root."""
    return next((s for s in STAGE_TABLE if attr in s.root_attrs), None)


def with_check(check: PostCheck) -> tuple[str, ...]:
    """Names of the stages after which the run makes `check`."""
    return tuple(s.name for s in STAGE_TABLE if s.check == check)


def upstream_sections() -> tuple[str, ...]:
    """The config sections the cache key of every stage downstream of the cache hashes: the
    stats stage's key sections (`pipeline.stages.common.upstream_key`)."""
    return STATS.key_sections
