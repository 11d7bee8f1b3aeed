"""Sensor variants of a synthetic recording: other LiDARs, drivers, rates and camera models.

The default recording follows GrandTour's sensors and drivers. Real users bring others, and
ingest must keep their recordings: rings numbered otherwise or absent, non-repetitive scans,
other conventions for a missing return, other point-time fields, clouds merged from two
sensors, other odometry rates, other camera models. A variant (`SynthConfig.variant`,
`m3gd synth --variant NAME`) changes one such property and nothing else: the same scene, the
same motion, the same ground truth. `VARIANTS` maps each name to its `Variant`.

LiDAR point layouts (PointField name, offset, datatype; little endian):

- hesai: x, y, z, intensity float32 at 0, 4, 8, 12; ring uint16 at 16; timestamp float64
  absolute s at 18; point_step 26 (the default);
- velodyne: x, y, z float32 at 0, 4, 8; intensity float32 at 16; ring uint16 at 20; time
  float32 s relative to the header stamp at 24; point_step 32 (padding as the driver's);
- ouster: x, y, z float32 at 0, 4, 8; intensity float32 at 16; t uint32 ns from the header
  stamp at 20; ring uint16 at 24; point_step 32;
- livox: x, y, z, intensity float32 at 0, 4, 8, 12; tag, line uint8 at 16, 17; timestamp
  float64 absolute ns at 18 (as livox_ros_driver2); point_step 26 (`line` is a laser number,
  not an elevation ring);
- no ring: the hesai layout without its ring field (point_step 26, bytes 16-17 unused).

Point time follows `schemas.time_conventions`: each layout has its driver's convention
(NATIVE_TIME), and a `LidarSpec.time` puts another in the layout's time slot (same offset,
point_step grown when the type is wider). The `time` group is one variant per convention of
the declared table (`time_<dtype>_<unit>_<reference>` on the hesai layout), derived from it.

VARIANTS is assembled from GROUPS (group name -> its variants by name): adding a group of
variants is one entry there. Rig variants (transforms of a written mission) live in
`pipeline.synth.variants_rig`, which this module does not import (the LiDAR model imports
this one, and the rig variants write through `rosio`, which imports the LiDAR model).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from schemas.time_conventions import CONVENTIONS, DRIVERS, TIME_FIELDS, TimeConvention

F64 = npt.NDArray[np.float64]

# (name, offset, PointField datatype): INT8 1, UINT8 2, UINT16 4, UINT32 6, FLOAT32 7, FLOAT64 8
LAYOUTS: dict[str, tuple[list[tuple[str, int, int]], int]] = {
    "hesai": ([("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 7), ("ring", 16, 4),
               ("timestamp", 18, 8)], 26),
    "velodyne": ([("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 16, 7), ("ring", 20, 4),
                  ("time", 24, 7)], 32),
    "ouster": ([("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 16, 7), ("t", 20, 6),
                ("ring", 24, 4)], 32),
    "livox": ([("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 7), ("tag", 16, 2),
               ("line", 17, 2), ("timestamp", 18, 8)], 26),
    "noring": ([("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 7),
                ("timestamp", 18, 8)], 26),
}  # fmt: skip
NUMPY_OF = {1: "<i1", 2: "<u1", 4: "<u2", 5: "<i4", 6: "<u4", 7: "<f4", 8: "<f8", 9: "<i8",
            10: "<u8"}  # fmt: skip
"""PointField datatype -> numpy (INT64 9 and UINT64 10 as PCL and ros2/common_interfaces#301)."""
DATATYPE_OF = {np.dtype(v).name: k for k, v in NUMPY_OF.items()}
NATIVE_TIME: dict[str, TimeConvention] = {
    "hesai": DRIVERS["hesai (GrandTour)"], "velodyne": DRIVERS["velodyne"],
    "ouster": DRIVERS["ouster"], "livox": DRIVERS["livox_ros_driver2"],
    "noring": DRIVERS["hesai (GrandTour)"],
}  # fmt: skip
"""The point-time convention each layout's driver writes."""


def layout_fields(layout: str, time: TimeConvention | None = None
                  ) -> tuple[list[tuple[str, int, int]], int]:  # fmt: skip
    """(PointFields (name, offset, datatype), point_step) of a layout, its time slot holding
    `time` (None: the driver's own convention)."""
    fields, step = LAYOUTS[layout]
    if time is None:
        return fields, step
    out = []
    for name, offset, datatype in fields:
        if name in TIME_FIELDS:
            name, datatype = time.field, DATATYPE_OF[time.dtype]
            step = max(step, offset + np.dtype(time.dtype).itemsize)
        out.append((name, offset, datatype))
    return out, step


def layout_dtype(layout: str, time: TimeConvention | None = None) -> np.dtype[np.void]:
    """The structured point dtype of a layout (explicit offsets and point_step)."""
    fields, step = layout_fields(layout, time)
    spec = {"names": [f[0] for f in fields], "formats": [NUMPY_OF[f[2]] for f in fields],
            "offsets": [f[1] for f in fields], "itemsize": step}  # fmt: skip
    dtype: np.dtype[np.void] = np.dtype(spec)  # type: ignore[call-overload]
    return dtype


@dataclass(frozen=True)
class LidarSpec:
    """A LiDAR and its driver.

    elevations_deg (B,): beam elevations (spinning pattern) in firing order within a column;
    ring_ids (B,): the ring number the driver writes for each beam; pattern: `spin` (columns
    of B beams over one rotation) or `livox` (a non-repetitive rosette, about 70 deg wide,
    looking along the robot's forward axis); layout: a key of LAYOUTS; invalid: how a missing
    return is written, `None` to leave it out of the cloud, else `nan` (x, y, z NaN), `x_nan`
    (x NaN, y = z = 0), `zero` or `posinf`; dense: the is_dense flag; merged: a second, tilted
    sensor's sweep in the same cloud (its frame moved into the first's, ring numbers reused);
    time: the point-time convention (None: the layout's driver's, NATIVE_TIME). The header
    stamps the sweep's first point, its last for a `header` convention (offsets <= 0).
    """

    elevations_deg: tuple[float, ...] = tuple(np.arange(-16.0, 16.0, 1.0).tolist())
    ring_ids: tuple[int, ...] = tuple(range(32))
    pattern: str = "spin"
    layout: str = "hesai"
    invalid: str | None = None
    dense: bool = False
    merged: bool = False
    time: TimeConvention | None = None

    @property
    def time_convention(self) -> TimeConvention:
        """The convention the points' time is written in."""
        return self.time or NATIVE_TIME[self.layout]

    def fields(self) -> tuple[list[tuple[str, int, int]], int]:
        """(PointFields, point_step) written (`layout_fields`)."""
        return layout_fields(self.layout, self.time)

    @property
    def beams(self) -> int:
        """Beams fired per column."""
        return len(self.elevations_deg)


VLP16_ELEVATIONS = tuple(float(e) for e in (-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3,
                                            13, -1, 15))  # fmt: skip
"""VLP-16 laser elevations in firing order (laser id 0..15)."""
VLP16_RINGS = tuple(int(r) for r in np.argsort(np.argsort(VLP16_ELEVATIONS)))
"""The velodyne driver's ring: a laser's rank by elevation (ring 0 lowest)."""


@dataclass(frozen=True)
class Variant:
    """One sensor variant: its LiDAR, odometry rate (None: the config's), camera model
    (`equidistant`, `plumb_bob`, `rational_polynomial`) and frame names (None: the config's)."""

    description: str
    lidar: LidarSpec = field(default_factory=LidarSpec)
    odom_hz: float | None = None
    camera_model: str = "equidistant"
    lidar_frame: str | None = None
    camera_frame: str | None = None


SENSORS: dict[str, Variant] = {
    "default": Variant("GrandTour's sensors: Hesai XT32, 32 rings, float64 absolute time"),
    "vlp16": Variant("VLP-16-like: 16 rings at -15..15 deg, velodyne layout, float32 relative "
                     "time", LidarSpec(VLP16_ELEVATIONS, VLP16_RINGS, layout="velodyne")),
    "rings_firing_order": Variant(
        "VLP-16 with the ring field in firing order (laser id, not by elevation)",
        LidarSpec(VLP16_ELEVATIONS, tuple(range(16)), layout="velodyne")),
    "rings_reversed": Variant("32 rings numbered from the top (ring 0 highest)",
                              LidarSpec(ring_ids=tuple(range(31, -1, -1)))),
    "no_ring": Variant("no ring field", LidarSpec(layout="noring")),
    "livox": Variant("Livox-like non-repetitive rosette scan, no rings (a laser `line` field), "
                     "float64 absolute ns time", LidarSpec(pattern="livox", layout="livox")),
    "missing_nan": Variant("missing returns kept as all-NaN points (organized cloud)",
                           LidarSpec(invalid="nan")),
    "missing_x_nan": Variant("missing returns as x = NaN, y = z = 0", LidarSpec(invalid="x_nan")),
    "missing_zero": Variant("missing returns as all-zero points", LidarSpec(invalid="zero")),
    "missing_inf": Variant("missing returns as +Inf (REP 117: no return)",
                           LidarSpec(invalid="posinf")),
    "dense": Variant("is_dense true, misses left out", LidarSpec(dense=True)),
    "dense_with_nan": Variant("is_dense true yet holding NaN missing returns",
                              LidarSpec(invalid="nan", dense=True)),
    "time_u32_ns": Variant("Ouster-like: uint32 ns point time from the first point (which the "
                           "header stamps)", LidarSpec(layout="ouster")),
    "merged": Variant("one cloud merged from two sensors (the second tilted and turned)",
                      LidarSpec(merged=True)),
    "frames": Variant("other frame names (velodyne, cam_<camera>_optical_frame)",
                      lidar_frame="velodyne", camera_frame="cam_{camera}_optical_frame"),
    "odom_50hz": Variant("odometry at 50 Hz", odom_hz=50.0),
    "odom_400hz": Variant("odometry at 400 Hz", odom_hz=400.0),
    "plumb_bob": Variant("pinhole cameras, plumb_bob distortion (5 coefficients)",
                         camera_model="plumb_bob"),
    "rational_polynomial": Variant("pinhole cameras, rational_polynomial distortion "
                                   "(8 coefficients)", camera_model="rational_polynomial"),
}  # fmt: skip
"""The sensor variants by name, most common first after the default."""


def time_variants() -> dict[str, Variant]:
    """One variant per convention of the declared table, on the hesai layout."""
    return {f"time_{c.name}": Variant(f"point time {c.describe()}", LidarSpec(time=c))
            for c in CONVENTIONS}  # fmt: skip


GROUPS: dict[str, dict[str, Variant]] = {
    "sensors": SENSORS,
    "time": time_variants(),
}
"""Variant groups (`m3gd bench variants --only <group>`); a new group is one entry here."""
VARIANTS: dict[str, Variant] = {n: v for group in GROUPS.values() for n, v in group.items()}
"""Every variant by name."""


def variant_help() -> str:
    """The variant groups and names (for --help)."""
    return "; ".join(f"{g}: {', '.join(vs)}" for g, vs in GROUPS.items())

