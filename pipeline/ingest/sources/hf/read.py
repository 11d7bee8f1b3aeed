"""`ingest_hf`: a mission folder in the Hugging Face layout to the same recording index as bags.

Each topic group is fed, row by row in `timestamp` order of rows, as stamped records to the
ingest core's gated pass (`pipeline.ingest.core.gated_pass`), which runs the bag path's stamp
gate (duplicate and out-of-order stamps refused, gaps rejected), plausibility checks (sweeps:
`checks.sweep_checks`; odometry: the jump filter and the quaternion norm; images: the drift
check against the neighbouring frames, `checks.image_drift`) and reject log, so good rows
around a bad one are kept and the bad one is a reject naming file, array and row.
Cameras: image i is `images/<group>/<i:06d>.jpeg`, decoded and rectified as a bag image, held
until the camera's next image is decoded (the drift check), then numbered and handed on.
LiDAR: one chunk of scans in memory (`points.ScanReader`). Odometry: `pose_pos` (N, 3),
`pose_orien` (N, 4) x, y, z, w. Index rows name where a row lives: `file` is the JPEG path or
the store group (`data/<group>`), `topic` the group, `ordinal` the row, `bag_time_ns` the stamp
(the release has no log time). The accounting table has one row per group, file `data/<group>`:
rows read, kept (an index row) and rejected (a reject row for that row, whatever its file).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline.ingest.calib.camera import Rectifier
from pipeline.ingest.checks.damage import DamagedRegion
from pipeline.ingest.checks.image_drift import jpeg_cells
from pipeline.ingest.checks.pose_checks import quat_norm_problem
from pipeline.ingest.checks.rejects import Reject, Tally, warning_lines
from pipeline.ingest.checks.sweep_checks import SweepPoints, sweep_problems
from pipeline.ingest.core.gated_pass import (
    GatedPass,
    Indexed,
    Record,
    check_notes,
    check_rows,
    emit_image,
)
from pipeline.ingest.core.stream import MAX_POSITION_M, ImageSink, Writers
from pipeline.ingest.errors import CorruptImageError, RowReject
from pipeline.ingest.index.ingest_result import IngestResult, index_writers, write_checks
from pipeline.ingest.sources.hf.calib import read_hf_static
from pipeline.ingest.sources.hf.points import BadScan, ScanReader, keep_mask
from pipeline.ingest.sources.hf.store import DECODE_ERRORS, IMAGES_DIR, BadChunk, HfStore
from pipeline.ingest.sources.pointcloud import MAX_COORD_M, convention_columns, sweep_counts
from pipeline.ingest.sources.static import calibration_rows
from schemas.config import IngestConfig
from schemas.errors import DataError
from schemas.recording_index import (
    ACCOUNTING,
    CALIBRATION,
    IndexTableWriter,
    Reason,
    index_dir,
    table_path,
    write_index_table,
)


def hf_pass(store: HfStore, group: str, out: Writers, tally: Tally, table: IndexTableWriter,
            **kw: Any) -> GatedPass:  # fmt: skip
    """The core's gated pass (`core.gated_pass`) over one topic group: accounted as
    (`data/<group>`, group), stamp refusals and gaps naming `data/<group>/timestamp`."""
    return GatedPass(out, group, (store.where(group), group), store.where(group, "timestamp"),
                     table, tally, **kw)  # fmt: skip


def group_records(store: HfStore, group: str, payloads: Iterator[tuple[int, Any]],
                  damaged: Callable[[BadChunk], None]) -> Iterator[Record]:
    """The group's rows as stamped records; a row whose stamp cannot be read or used carries
    why (a chunk that cannot be read is reported once as damage by `damaged`)."""
    stamps, ok = store.stamps(group)
    where = store.where(group, "timestamp")
    for row, payload in payloads:
        if ok[row]:
            yield Record(row, int(stamps[row]), payload)
            continue
        bad = store.stamp_damage(group, row)
        if bad is not None:
            damaged(bad)
            why = RowReject(Reason.UNDECODABLE_MESSAGE, bad.array, f"row {row}: {bad.detail}")
        else:
            raw = store.array(group, "timestamp")[row]
            why = RowReject(Reason.UNDECODABLE_MESSAGE, where,
                            f"{where} row {row}: timestamp {raw!r} is not a usable time")
        yield Record(row, why, payload)


@dataclass
class ChunkDamage:
    """The damage rows of one group: one per chunk that cannot be read."""

    store: HfStore
    group: str
    out: Writers
    chunks: set[BadChunk] = field(default_factory=set)

    def __call__(self, chunk: BadChunk) -> None:
        """One damage row and one `damaged_region` reject per chunk that cannot be read (its
        rows are rejected one by one too). A store has no byte offsets: bytes 0-0, the rows
        and the readable stamps around them say where."""
        if chunk in self.chunks:
            return
        self.chunks.add(chunk)
        stamps, ok = self.store.stamps(self.group)
        before = [int(stamps[r]) for r in range(chunk.first, -1, -1) if ok[r]][:1]
        after = [int(stamps[r]) for r in range(chunk.last, len(stamps)) if ok[r]][:1]
        first, last = (before or after or [0])[0], (after or before or [0])[0]
        region = DamagedRegion(chunk.array, 0, 0, (self.group,), first, last,
                               chunk.last - chunk.first + 1, chunk.detail)  # fmt: skip
        self.out.damage.append(region.row())
        self.out.rejects.add(region.reject())


def ingest_hf(mission_dir: Path, out_dir: Path, cfg: IngestConfig,
              image_sink: ImageSink | None, recording: str) -> IngestResult:  # fmt: skip
    """Index one Hugging Face mission folder (see the module docstring)."""
    t0 = time.perf_counter()
    idx = index_dir(out_dir, recording)
    store = HfStore.open(mission_dir)
    check_groups(store, cfg)
    calib = read_hf_static(store, cfg)
    write_index_table(pa.Table.from_pylist(calibration_rows(calib, cfg), schema=CALIBRATION),
                      CALIBRATION, table_path(idx, "calibration"))  # fmt: skip
    frames: dict[str, int] = {}
    tally = Tally.empty()
    passes: list[GatedPass] = []
    with index_writers(idx) as out:
        for reject in [*calib.rejects, *_missing_cameras(store, cfg)]:
            out.rejects.add(reject)
        passes.extend(_camera(store, cfg, cam, calib.rectifiers[cam], image_sink, out, frames,
                              tally) for cam in cfg.cameras if cam in calib.rectifiers)  # fmt: skip
        passes.append(_sweeps(store, cfg, out, tally))
        passes.extend(_odometry(store, cfg, out, tally))
        write_index_table(pa.Table.from_pylist(tally.rows(), schema=ACCOUNTING), ACCOUNTING,
                          table_path(idx, "accounting"))  # fmt: skip
        write_checks(idx, check_rows(passes))
    return IngestResult(
        recording=recording, index_dir=idx, images=frames, sweeps=out.sweeps.count,
        odometry=out.odometry.count, rejects=dict(out.rejects.counts),
        unaccounted=tally.unaccounted(),
        decode_reduction={c: r.reduction for c, r in calib.rectifiers.items()},
        seconds=time.perf_counter() - t0,
        warnings=warning_lines(out.rejects.notable, dict(out.rejects.counts),
                               table_path(idx, "rejects")) + check_notes(passes),
        input_format=f"hf-zarr (Zarr v{store.version})", checks=check_rows(passes),
    )  # fmt: skip


def check_groups(store: HfStore, cfg: IngestConfig) -> None:
    """DataError (with a did-you-mean) when the tf or LiDAR group, or every camera, is absent,
    or when the config declares more LiDARs than the layout's one LiDAR group."""
    hf = cfg.hf
    rig = cfg.topics.lidar_rig()
    if len(rig) > 1:
        raise DataError(f"{store.mission_dir}: the Hugging Face layout holds one LiDAR group "
                        f"(ingest.hf.lidar_group); ingest.topics.lidars declares {len(rig)}")
    cams = [hf.group(c) for c in cfg.cameras]
    store.group(hf.tf_group, "static transform")
    store.group(hf.lidar_group, "LiDAR")
    if not any(store.has(c) for c in cams):
        store.group(cams[0], "camera")


def _missing_cameras(store: HfStore, cfg: IngestConfig) -> list[Reject]:
    """A missing-topic reject (with a did-you-mean) per configured camera without a group."""
    names = [cfg.hf.group(c) for c in cfg.cameras]
    return [Reject("", n, 0, Reason.MISSING_TOPIC, store.missing(n, "camera"))
            for n in names if not store.has(n)]  # fmt: skip


def _camera(store: HfStore, cfg: IngestConfig, cam: str, rect: Rectifier,
            sink: ImageSink | None, out: Writers, frames: dict[str, int],
            tally: Tally) -> GatedPass:  # fmt: skip
    """Every row of one camera group: JPEG read, rectified, judged against its neighbouring
    frames (the drift check), handed to the sink and indexed."""
    group = cfg.hf.group(cam)
    gp = hf_pass(store, group, out, tally, out.images, kind="image", checks=cfg.checks)
    n = int(store.array(group, "timestamp").shape[0])
    if n and not (store.mission_dir / IMAGES_DIR / group).is_dir():
        out.rejects.add(Reject(f"{IMAGES_DIR}/{group}", group, 0, Reason.MISSING_TOPIC,
                               f"no folder {IMAGES_DIR}/{group} for the {n} rows of "
                               f"{store.where(group, 'timestamp')}"))  # fmt: skip
        return gp

    def handle(row: int, stamp: int, _: Any) -> Indexed:
        path = store.image_path(group, row)
        rel = str(path.relative_to(store.mission_dir))
        try:
            data = np.frombuffer(path.read_bytes(), dtype=np.uint8)
        except FileNotFoundError as err:
            raise RowReject(Reason.MISSING_FILE, rel, f"{rel}: no JPEG for row {row} of "
                            f"{store.where(group, 'timestamp')}") from err  # fmt: skip
        try:
            decoded = rect.decode(data, f"{rel} (row {row} of {store.where(group)})")
        except CorruptImageError as err:
            raise RowReject(Reason.CORRUPT_JPEG, rel, str(err)) from err
        cells = jpeg_cells(data, decoded, stamp, rect.reduction) if gp.drift else None
        return Indexed({"camera": cam, "frame": -1, "stamp_ns": stamp,
                        **gp.location(row, stamp, rel), "jpeg_bytes": int(data.size)}, rel,
                       cells=cells, emit=emit_image(cam, stamp, rect.remap(decoded), rect.K_out,
                                                    sink, frames))  # fmt: skip

    damaged = ChunkDamage(store, group, out)
    gp.run(group_records(store, group, ((i, None) for i in range(n)), damaged), handle)
    return gp


def _sweeps(store: HfStore, cfg: IngestConfig, out: Writers, tally: Tally) -> GatedPass:
    """Every LiDAR scan: counts of its valid points, its plausibility checks (one chunk of
    scans in memory)."""
    group, lidar = cfg.hf.lidar_group, cfg.topics.lidar_rig()[0].name
    gp = hf_pass(store, group, out, tally, out.sweeps, kind="sweep", number="sweep",
                 checks=cfg.checks)  # fmt: skip
    reader = ScanReader(store, group)
    file = store.where(group)
    damaged = ChunkDamage(store, group, out)
    active = gp.fit.active if gp.fit is not None else (lambda _: False)

    def handle(row: int, stamp: int, scan: Any) -> Indexed:
        if isinstance(scan, BadScan):
            if scan.chunk is not None:
                damaged(BadChunk(store.where(group, "points"), *scan.chunk, scan.detail))
            raise RowReject(Reason.BAD_POINTCLOUD, scan.detail.split(" ")[0], scan.detail)
        xyz, intensity = scan
        c, keep = keep_mask(xyz)
        if c.valid == 0:
            raise RowReject(Reason.EMPTY_SWEEP, file,
                            f"{store.where(group, 'points')} row {row}: no valid points: "
                            f"{c.total} in the scan, {c.kinds()}, {c.corrupt} corrupt")
        if c.corrupt:  # NaN/Inf are invalid returns; a point beyond any range is damage
            raise RowReject(Reason.NONFINITE_POINTS, store.where(group, "points"),
                            f"{store.where(group, 'points')} row {row}: "
                            f"{c.corrupt} of {c.total} points corrupt (beyond "
                            f"{MAX_COORD_M:g} m): a damaged scan")  # fmt: skip
        points = SweepPoints(xyz[keep].astype(np.float64), None,
                             intensity[keep].astype(np.float64))  # fmt: skip
        return Indexed({"lidar": lidar, "stamp_ns": stamp, **gp.location(row, stamp, file),
                        **sweep_counts(c), "t_first_ns": stamp, "t_last_ns": stamp,
                        **convention_columns(None)},
                       store.where(group, "points"),
                       sweep_problems(points, cfg.checks, active))  # fmt: skip

    gp.run(group_records(store, group, reader.rows(), damaged), handle)
    return gp


def _odometry(store: HfStore, cfg: IngestConfig, out: Writers, tally: Tally) -> list[GatedPass]:
    """Every odometry row as T_odom_base (quaternion x, y, z, w) through the pose checks; bad
    poses are rejects."""
    hf, base = cfg.hf, cfg.topics.base_frame
    if not store.has(hf.odometry_group):
        out.rejects.add(Reject("", hf.odometry_group, 0, Reason.MISSING_TOPIC,
                               store.missing(hf.odometry_group, "odometry")))  # fmt: skip
        return []
    group = hf.odometry_group
    gp = hf_pass(store, group, out, tally, out.odometry, kind="pose", checks=cfg.checks)
    damaged = ChunkDamage(store, group, out)
    frame = str(store.attrs(group).get("frame_id") or cfg.topics.odom_frame)
    pos_a, quat_a = store.array(group, "pose_pos"), store.array(group, "pose_orien")

    def rows() -> Iterator[tuple[int, Any]]:
        n, step = int(pos_a.shape[0]), int(pos_a.chunks[0])
        for start in range(0, n, step):
            stop = min(n, start + step)
            try:
                pos = np.asarray(pos_a[start:stop], np.float64)
                quat = np.asarray(quat_a[start:stop], np.float64)
            except DECODE_ERRORS as err:
                name = "pose_pos" if _unreadable(pos_a, start, stop) else "pose_orien"
                bad = store.bad_chunk(group, name, start, stop, err)
                yield from ((row, bad) for row in range(start, stop))
                continue
            for k in range(pos.shape[0]):
                yield start + k, (pos[k], quat[k])

    def handle(row: int, stamp: int, pose: Any) -> Indexed:
        if isinstance(pose, BadChunk):
            damaged(pose)
            raise RowReject(Reason.UNDECODABLE_MESSAGE, pose.array, f"row {row}: {pose.detail}")
        pos, quat = pose
        bad = _bad_pose(pos, quat)
        if bad:
            raise RowReject(Reason.BAD_POSE, store.where(group),
                            f"{store.where(group)}/pose_pos, pose_orien row {row}: {bad}")
        problem = quat_norm_problem(quat, cfg.checks.quat_norm_tol)
        return Indexed({"stamp_ns": stamp, "frame_id": frame, "child_frame_id": base,
                        "position": pos.tolist(),
                        "quat_xyzw": (quat / np.linalg.norm(quat)).tolist()},
                       store.where(group), {"quat_norm": problem})  # fmt: skip

    gp.run(group_records(store, group, rows(), damaged), handle)
    return [gp]


def _unreadable(arr: Any, start: int, stop: int) -> bool:
    """Whether rows [start, stop) of `arr` cannot be read."""
    try:
        arr[start:stop]
    except DECODE_ERRORS:
        return True
    return False


def _bad_pose(pos: Any, quat: Any) -> str:
    """Why a pose is unusable ('' when it is fine): the bag reader's rules."""
    if not (np.isfinite(pos).all() and np.isfinite(quat).all()) or np.linalg.norm(quat) < 1e-9:
        return f"non-finite or zero pose: position {pos.tolist()}, quat {quat.tolist()}"
    if np.abs(pos).max() > MAX_POSITION_M:
        return f"position {pos.tolist()} m is beyond {MAX_POSITION_M:g} m: a corrupt pose"
    return ""
