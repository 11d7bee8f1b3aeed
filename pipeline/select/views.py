"""`select_views`: per image the nearest sweep, Δτ, and the LiDAR-to-camera chain via odometry.

Reads the recording index written by ingest and writes `selection.parquet` beside it (one row
per image). A view is rejected (row kept, status 'rejected', reason code) when there is no sweep,
when |Δτ| exceeds `max_abs_dt_s`, or when odometry cannot be interpolated at the image or the
sweep stamp within `max_odom_gap_s` (never extrapolated). Sweeps no accepted view selects are
counted; downstream stages never decode them. A plain function: runs in-process or on Dask.

`time_offset_s` (camera clock minus LiDAR clock, known from calibration or estimated) is
subtracted from every image stamp before the nearest sweep, Δτ and the odometry poses are
found; the row's `stamp_ns` stays the image's own stamp (its identity in the index).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from packets.poses import F64, compose, interpolate_poses, lidar_to_camera, nearest_stamps
from schemas.config import IngestConfig, SelectConfig
from schemas.errors import DataError
from schemas.recording_index import (
    CALIBRATION,
    IMAGES,
    ODOMETRY,
    SELECTION,
    SELECTION_LIDARS,
    SWEEPS,
    Reason,
    ViewStatus,
    read_index_table,
    table_path,
    write_index_table,
)


@dataclass
class SelectResult:
    """Counts of the selection: views, accepted, rejected by reason, sweeps used and unused."""

    index_dir: Path
    views: int = 0
    accepted: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    sweeps_total: int = 0
    sweeps_selected: int = 0
    sweeps_unselected: int = 0
    lidar_views: dict[str, int] = field(default_factory=dict)
    """Merging several LiDARs: the views each LiDAR adds points to (its row accepted)."""


@dataclass(frozen=True)
class Odometry:
    """Odometry samples: stamps (M,) int64 ns, positions (M, 3), quaternions (M, 4)."""

    stamps: np.ndarray
    pos: np.ndarray
    quat: np.ndarray

    def at(self, query_ns: np.ndarray, max_gap_ns: int) -> tuple[F64, np.ndarray]:
        """T_odom_base (N, 4, 4) at `query_ns` and (N,) ok (inside, gap within bound)."""
        s = interpolate_poses(self.stamps, self.pos, self.quat, query_ns, max_gap_ns)
        return s.T, s.ok


def load_odometry(idx: Path) -> Odometry:
    """Odometry table as arrays."""
    path = table_path(idx, "odometry")
    t = read_index_table(path, ODOMETRY)
    pos = np.asarray(t.column("position").to_pylist(), dtype=np.float64).reshape(-1, 3)
    quat = np.asarray(t.column("quat_xyzw").to_pylist(), dtype=np.float64).reshape(-1, 4)
    stamps = t.column("stamp_ns").to_numpy().astype(np.int64)
    bad = np.flatnonzero(np.diff(stamps) <= 0)
    if bad.size:
        i = int(bad[0])
        raise DataError(f"{path}: odometry stamps must be strictly increasing; row {i + 1} "
                         f"({stamps[i + 1]} ns) follows row {i} ({stamps[i]} ns); ingest again")
    return Odometry(stamps, pos, quat)


def _calibration(idx: Path) -> dict[str, dict[str, object]]:
    """Calibration rows by sensor name."""
    rows = read_index_table(table_path(idx, "calibration"), CALIBRATION).to_pylist()
    return {str(r["sensor"]): r for r in rows}


def _mat(values: object, n: int) -> F64:
    """A flattened row-major matrix as an (n, n) float64 array."""
    return np.asarray(values, dtype=np.float64).reshape(n, n)


@dataclass(frozen=True)
class LidarSweeps:
    """One LiDAR's sweeps: name, (S,) sweep ids, (S,) increasing stamps ns, T_base_lidar."""

    name: str
    ids: np.ndarray
    stamps: np.ndarray
    T_base_lidar: F64


def _lidar_sweeps(index_dir: Path, sweeps: pa.Table, lidar: str,
                  calib: dict[str, dict[str, object]]) -> LidarSweeps:
    """The sweeps and extrinsic of LiDAR `lidar`; DataError when they are unusable."""
    rows = sweeps.filter(pc.equal(sweeps.column("lidar"), lidar))
    stamps = rows.column("stamp_ns").to_numpy().astype(np.int64)
    if stamps.size > 1 and bool((np.diff(stamps) <= 0).any()):
        raise DataError(f"{table_path(index_dir, 'sweeps')}: sweep stamps of LiDAR {lidar!r} "
                        "are not increasing")
    if lidar not in calib:
        raise DataError(f"{table_path(index_dir, 'calibration')}: no row of LiDAR {lidar!r}; "
                        "ingest again")
    return LidarSweeps(lidar, rows.column("sweep").to_numpy().astype(np.int64), stamps,
                       _mat(calib[lidar]["T_base_sensor"], 4))


def select_views(index_dir: Path, cfg: SelectConfig, ingest_cfg: IngestConfig) -> SelectResult:
    """Select the nearest sweep of the views' LiDAR (`SelectConfig.lidar_of`) for every indexed
    image and write `selection.parquet`; the other LiDARs' sweeps are not counted.

    When `select.lidar` merges several LiDARs, `selection_lidars.parquet` also holds a row per
    view and merged LiDAR (the same rules, each LiDAR's own sweeps and extrinsic); otherwise
    a table left by an earlier merging run is removed.
    """
    images = read_index_table(table_path(index_dir, "images"), IMAGES)
    sweeps = read_index_table(table_path(index_dir, "sweeps"), SWEEPS)
    odo = load_odometry(index_dir)
    calib = _calibration(index_dir)
    max_gap = round(cfg.max_odom_gap_s * 1e9)
    lidars = [_lidar_sweeps(index_dir, sweeps, x.name, calib)
              for x in cfg.lidars_of(ingest_cfg.topics)]
    ref = lidars[0]
    parts, merged = [], []
    result = SelectResult(index_dir, sweeps_total=int(ref.stamps.size))
    used = np.zeros(ref.stamps.size, dtype=bool)
    for cam in [c for c in ingest_cfg.cameras if c in calib]:
        rows = images.filter(pc.equal(images.column("camera"), cam))
        for lidar in lidars if cfg.merges() else lidars[:1]:
            table, ok_sweeps = _select_camera(cam, rows, lidar, odo, calib[cam], cfg, max_gap)
            if lidar is ref:
                used[ok_sweeps] = True
                parts.append(table)
            if cfg.merges():
                merged.append(_lidar_rows(table, lidar.name))
    out = pa.concat_tables(parts) if parts else SELECTION.empty_table()
    write_index_table(out, SELECTION, table_path(index_dir, "selection"))
    _write_merged(index_dir, merged, cfg.merges(), result)
    status = np.asarray(out.column("status").to_pylist(), dtype=object)
    reasons = np.asarray(out.column("reason").to_pylist(), dtype=object)
    result.views = out.num_rows
    result.accepted = int((status == ViewStatus.OK.value).sum())
    rejected = reasons[status != ViewStatus.OK.value]
    result.rejected = {str(r): int((rejected == r).sum()) for r in sorted(set(rejected))}
    result.sweeps_selected = int(used.sum())
    result.sweeps_unselected = result.sweeps_total - result.sweeps_selected
    return result


def _lidar_rows(table: pa.Table, lidar: str) -> pa.Table:
    """One camera's selection rows for LiDAR `lidar` as rows of `selection_lidars`."""
    cols = {f.name: table.column(f.name) for f in SELECTION_LIDARS if f.name != "lidar"}
    cols["lidar"] = pa.array([lidar] * table.num_rows, pa.string())
    return pa.table({f.name: cols[f.name] for f in SELECTION_LIDARS})


def _write_merged(index_dir: Path, parts: list[pa.Table], merges: bool,
                  result: SelectResult) -> None:
    """Write `selection_lidars.parquet` (merging) or remove a stale one; count kept rows."""
    path = table_path(index_dir, "selection_lidars")
    if not merges:
        path.unlink(missing_ok=True)
        return
    table = pa.concat_tables(parts) if parts else SELECTION_LIDARS.empty_table()
    write_index_table(table, SELECTION_LIDARS, path)
    ok = table.filter(pc.equal(table.column("status"), ViewStatus.OK.value))
    names = ok.column("lidar").to_pylist()
    result.lidar_views = {n: names.count(n) for n in dict.fromkeys(
        table.column("lidar").to_pylist())}


def _select_camera(
    cam: str,
    rows: pa.Table,
    lidar: LidarSweeps,
    odo: Odometry,
    calib: dict[str, object],
    cfg: SelectConfig,
    max_gap: int,
) -> tuple[pa.Table, np.ndarray]:
    """Selection rows of one camera against one LiDAR's sweeps, and the positions in them of
    the sweeps its accepted views use."""
    sweep_id, sweep_t, T_base_lidar = lidar.ids, lidar.stamps, lidar.T_base_lidar
    stamp = rows.column("stamp_ns").to_numpy().astype(np.int64)
    tau = stamp - round(cfg.time_offset_s * 1e9)  # image time on the LiDAR / odometry clock
    n = tau.size
    T_base_cam = _mat(calib["T_base_sensor"], 4)
    K_out = np.asarray(calib["K_out"], dtype=np.float64)
    if sweep_t.size:
        pos, dtau = nearest_stamps(tau, sweep_t)
        tau_p, sweep = sweep_t[pos], sweep_id[pos]
    else:
        pos, sweep, dtau, tau_p = np.full(n, -1), np.full(n, -1), np.zeros(n), tau.copy()
    T_img, ok_img = odo.at(tau, max_gap)
    T_swp, ok_swp = odo.at(tau_p, max_gap)
    reason = np.full(n, "", dtype=object)
    reason[~(ok_img & ok_swp)] = Reason.ODOM_GAP.value
    reason[np.abs(dtau) > cfg.max_abs_dt_s] = Reason.DTAU_EXCEEDED.value
    if not sweep_t.size:
        reason[:] = Reason.NO_SWEEP.value
    ok = reason == ""
    T_cam_lidar = lidar_to_camera(T_base_cam, T_img, T_swp, T_base_lidar)
    T_world_cam = compose(T_img, T_base_cam)
    T_cam_lidar[~ok] = np.eye(4)
    T_world_cam[~ok_img] = np.eye(4)
    table = pa.table(
        {
            "camera": pa.array([cam] * n, pa.string()),
            "frame": rows.column("frame"),
            "stamp_ns": pa.array(stamp, pa.int64()),
            "sweep": pa.array(sweep, pa.int64()),
            "sweep_stamp_ns": pa.array(np.where(sweep >= 0, tau_p, -1), pa.int64()),
            "dtau_s": pa.array(dtau, pa.float64()),
            "T_cam_lidar": _fixed(T_cam_lidar.reshape(n, 16), 16),
            "T_world_cam": _fixed(T_world_cam.reshape(n, 16), 16),
            "K_out": _fixed(np.tile(K_out, (n, 1)), 9),
            "status": pa.array(np.where(ok, ViewStatus.OK.value, ViewStatus.REJECTED.value)),
            "reason": pa.array(reason.astype(str), pa.string()),
        }
    )
    return table, pos[ok]


def _fixed(values: np.ndarray, width: int) -> pa.FixedSizeListArray:
    """(n, width) float64 rows as a fixed-size list array."""
    flat = pa.array(np.ascontiguousarray(values, dtype=np.float64).ravel(), pa.float64())
    return pa.FixedSizeListArray.from_arrays(flat, width)
