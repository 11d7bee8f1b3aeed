"""`ingest_kitti360`: a KITTI-360 sequence (`kitti360.Kitti360Layout`) to the recording index.

Each sensor folder is fed, frame by frame in timestamps.txt order, as stamped records to the
ingest core's gated pass (`core.gated_pass`), which runs the bag path's stamp gate (duplicate and
out-of-order stamps refused, gaps rejected), plausibility checks (sweeps: `checks.sweep_checks`,
point limits; poses: the jump filter; images: not the drift check, which looks for damaged
JPEG data and a PNG is lossless) and reject log, so good frames around a bad one are kept and
the bad one is a reject naming the file and line.
Cameras: `data_rect/NNNNNNNNNN.png` decoded and resampled to the output size as a bag image.
Velodyne: `data/NNNNNNNNNN.bin` with the bag reader's point rules (invalid returns counted by
kind, a point beyond MAX_COORD_M is damage). **Point time** (declared, not guessed): KITTI-360
sweeps carry no per-point time; every point of a sweep takes the sweep's timestamps.txt stamp,
recorded as the index's header-stamp convention (time_* columns "", t_first_ns = t_last_ns =
stamp_ns). Odometry: poses.txt rows, T_world_pose at the stamp of `image_00` frame `frame`.
Index rows: `file` the PNG/.bin (the folder for a pose), `topic` the folder name (`poses` for
poses.txt), `ordinal` the frame, `bag_time_ns` the stamp (the layout has no log time).
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pyarrow as pa

from packets.poses import rot_to_quat
from pipeline.ingest.calib.camera import Rectifier
from pipeline.ingest.checks.rejects import Tally, warning_lines
from pipeline.ingest.checks.sweep_checks import SweepPoints, sweep_problems
from pipeline.ingest.core.gated_pass import (
    GatedPass,
    Indexed,
    Record,
    check_notes,
    check_rows,
    emit_image,
)
from pipeline.ingest.core.sinks import ImageSink, Writers
from pipeline.ingest.errors import CalibrationMismatchError, CorruptImageError, RowReject
from pipeline.ingest.index.ingest_result import IngestResult, index_writers, write_checks
from pipeline.ingest.sources.kitti360_calib import parse_poses, parse_stamp, parse_velodyne
from pipeline.ingest.sources.kitti360_layout import (
    VELODYNE,
    Kitti360Layout,
    camera_folders,
    read_kitti360_static,
)
from pipeline.ingest.sources.pointcloud import (
    MAX_COORD_M,
    PointCounts,
    Sweep,
    convention_columns,
    point_kinds,
    sweep_counts,
)
from pipeline.ingest.sources.static import calibration_rows
from schemas.config import IngestConfig
from schemas.errors import DataError, MissingDataError
from schemas.recording_index import (
    ACCOUNTING,
    CALIBRATION,
    IndexTableWriter,
    Reason,
    index_dir,
    table_path,
    write_index_table,
)

MAX_POSITION_M = 1e6
"""A pose farther than this (m) from the origin is corrupt (as for bag odometry)."""


def read_stamps(layout: Kitti360Layout, name: str) -> list[tuple[int, int | str]]:
    """(frame, stamp ns or why the line is unusable) per line of a sensor's timestamps.txt."""
    path = layout.sensor_dir(name) / "timestamps.txt"
    text = layout.text(path, f"{name} stamps")
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    out: list[tuple[int, int | str]] = []
    for i, line in enumerate(lines):
        try:
            out.append((i, parse_stamp(line, f"{layout.rel(path)} line {i + 1}")))
        except DataError as err:
            out.append((i, str(err)))
    return out


def sensor_pass(layout: Kitti360Layout, name: str, out: Writers, tally: Tally,
                table: IndexTableWriter, **kw: Any) -> GatedPass:  # fmt: skip
    """The core's gated pass (`core.gated_pass`) over one sensor folder (`poses` for
    poses.txt): accounted as (folder relative to the root, folder name), which stamp refusals
    and gaps name."""
    folder = layout.poses.parent if name == "poses" else layout.sensor_dir(name)
    rel = layout.rel(folder)
    return GatedPass(out, name, (rel, name), rel, table, tally, unit="frame", **kw)


def frame_records(stamps: Iterable[tuple[int, int | str]], where: str) -> Iterator[Record]:
    """(frame, stamp or why the line is unusable) as stamped records."""
    for frame, stamp in stamps:
        if isinstance(stamp, str):
            yield Record(frame, RowReject(Reason.UNDECODABLE_MESSAGE, where, stamp))
        else:
            yield Record(frame, stamp)


def ingest_kitti360(root: Path, out_dir: Path, cfg: IngestConfig, image_sink: ImageSink | None,
                    recording: str) -> IngestResult:  # fmt: skip
    """Index one KITTI-360 sequence (see the module docstring)."""
    t0 = time.perf_counter()
    layout = Kitti360Layout.open(root)
    if len(cfg.topics.lidar_rig()) > 1:
        raise DataError(f"{root}: KITTI-360 holds one Velodyne; ingest.topics.lidars declares "
                        f"{len(cfg.topics.lidar_rig())}")  # fmt: skip
    idx = index_dir(out_dir, recording)
    calib = read_kitti360_static(layout, cfg)
    write_index_table(pa.Table.from_pylist(calibration_rows(calib, cfg), schema=CALIBRATION),
                      CALIBRATION, table_path(idx, "calibration"))  # fmt: skip
    frames: dict[str, int] = {}
    tally = Tally.empty()
    passes: list[GatedPass] = []
    with index_writers(idx) as out:
        for reject in calib.rejects:
            out.rejects.add(reject)
        for cam, folder in camera_folders(cfg.cameras).items():
            if cam in calib.rectifiers:
                sp = sensor_pass(layout, folder, out, tally, out.images)  # no image check
                # applies to a lossless PNG (`_camera`)
                _camera(layout, sp, cam, calib.rectifiers[cam], image_sink, frames)
                passes.append(sp)
        passes += [
            _sweeps(layout, sensor_pass(layout, VELODYNE, out, tally, out.sweeps, kind="sweep",
                                        number="sweep", checks=cfg.checks),
                    cfg.topics.lidar_rig()[0].name, cfg),
            _poses(layout, sensor_pass(layout, "poses", out, tally, out.odometry, kind="pose",
                                       checks=cfg.checks), cfg),
        ]  # fmt: skip
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
        input_format=f"kitti360 (sequence {layout.seq}; sweeps without per-point time)",
        checks=check_rows(passes),
    )  # fmt: skip


def _camera(layout: Kitti360Layout, sp: GatedPass, cam: str, rect: Rectifier,
            sink: ImageSink | None, frames: dict[str, int]) -> None:  # fmt: skip
    """Every frame of one camera folder: PNG read, resampled, handed to the sink, indexed. The
    drift check does not judge it: it looks for the bands damaged JPEG data decodes to, and a
    lossless PNG cannot carry them (the bag path skips PNG and raw images alike)."""

    def handle(frame: int, stamp: int, _: Any) -> Indexed:
        path = layout.frame_file(sp.topic, frame)
        rel = layout.rel(path)
        try:
            data = path.read_bytes()
        except FileNotFoundError as err:
            raise RowReject(Reason.MISSING_FILE, rel, f"{rel}: no image for frame {frame} of "
                            f"{sp.key[0]}/timestamps.txt") from err  # fmt: skip
        msg = SimpleNamespace(data=np.frombuffer(data, np.uint8))
        try:
            decoded = rect.decode_message("png", msg, rel)
        except CorruptImageError as err:
            raise RowReject(Reason.CORRUPT_JPEG, rel, str(err)) from err
        except CalibrationMismatchError as err:
            raise RowReject(Reason.CALIBRATION_MISMATCH, rel,
                            f"{err} (S_rect of calibration/perspective.txt)") from err
        return Indexed({"camera": cam, "frame": -1, "stamp_ns": stamp,
                        **sp.location(frame, stamp, rel), "jpeg_bytes": len(data)}, rel,
                       cells=None, emit=emit_image(cam, stamp, rect.remap(decoded), rect.K_out,
                                                    sink, frames))  # fmt: skip

    sp.run(frame_records(read_stamps(layout, sp.topic), sp.key[0]), handle)


def sweep_points(data: bytes, where: str) -> tuple[PointCounts, Any, Any]:
    """Counts, kept xyz (n, 3) float32 and kept reflectance (n,) of one .bin sweep."""
    xyz, refl = parse_velodyne(data, where)
    kinds = point_kinds(xyz[:, 0], xyz[:, 1], xyz[:, 2])
    keep = kinds.keep
    return kinds.counts(), np.ascontiguousarray(xyz[keep]), np.nan_to_num(refl[keep])


def _sweeps(layout: Kitti360Layout, sp: GatedPass, lidar: str, cfg: IngestConfig) -> GatedPass:
    """Every Velodyne frame: the counts of its points, its plausibility checks (one sweep in
    memory)."""
    active = sp.fit.active if sp.fit is not None else (lambda _: False)

    def handle(frame: int, stamp: int, _: Any) -> Indexed:
        path = layout.frame_file(VELODYNE, frame)
        rel = layout.rel(path)
        try:
            c, xyz, refl = sweep_points(path.read_bytes(), rel)
        except FileNotFoundError as err:
            raise RowReject(Reason.MISSING_FILE, rel, f"{rel}: no sweep for frame {frame} of "
                            f"{sp.key[0]}/timestamps.txt") from err  # fmt: skip
        except DataError as err:
            raise RowReject(Reason.BAD_POINTCLOUD, rel, str(err)) from err
        if c.valid == 0:
            raise RowReject(Reason.EMPTY_SWEEP, rel, f"{rel}: no valid points: {c.total} in the "
                            f"sweep, {c.nonfinite} non-finite, {c.zero} at zero")  # fmt: skip
        if c.corrupt:
            raise RowReject(Reason.NONFINITE_POINTS, rel, f"{rel}: {c.corrupt} of {c.total} "
                            f"points beyond {MAX_COORD_M:g} m: a damaged sweep")  # fmt: skip
        points = SweepPoints(xyz.astype(np.float64), None, refl.astype(np.float64))
        return Indexed({"lidar": lidar, "stamp_ns": stamp, **sp.location(frame, stamp, rel),
                        **sweep_counts(c), "t_first_ns": stamp, "t_last_ns": stamp,
                        **convention_columns(None)}, rel,
                       sweep_problems(points, cfg.checks, active))  # fmt: skip

    sp.run(frame_records(read_stamps(layout, VELODYNE), sp.key[0]), handle)
    return sp


def _poses(layout: Kitti360Layout, sp: GatedPass, cfg: IngestConfig) -> GatedPass:
    """poses.txt rows as odometry (T_world_pose at image_00's frame stamps), through the pose
    checks (the jump filter; the quaternion is of a rotation matrix, unit by construction)."""
    rel = layout.rel(layout.poses)
    pose_frames, T = parse_poses(layout.text(layout.poses, "poses"), rel)
    stamps = dict(read_stamps(layout, "image_00"))
    by_frame = {int(f): T[i] for i, f in enumerate(pose_frames)}

    def rows() -> Iterator[tuple[int, int | str]]:
        for f in by_frame:
            stamp = stamps.get(f, f"{rel}: frame {f} is not a line of image_00/timestamps.txt "
                                  f"({len(stamps)} lines)")  # fmt: skip
            yield f, stamp

    def handle(frame: int, stamp: int, _: Any) -> Indexed:
        pose = by_frame[frame]
        if np.abs(pose[:3, 3]).max() > MAX_POSITION_M:
            raise RowReject(Reason.BAD_POSE, rel, f"{rel} frame {frame}: position "
                            f"{pose[:3, 3].tolist()} m is beyond {MAX_POSITION_M:g} m")
        return Indexed({"stamp_ns": stamp, "frame_id": cfg.topics.odom_frame,
                        "child_frame_id": cfg.topics.base_frame,
                        "position": pose[:3, 3].tolist(),
                        "quat_xyzw": rot_to_quat(pose[:3, :3]).tolist()}, rel)  # fmt: skip

    sp.run(frame_records(rows(), sp.key[0]), handle)
    return sp


def iter_kitti360_sweeps(root: Path, rows: Iterable[Mapping[str, Any]]) -> Iterator[Sweep]:
    """Decode indexed sweeps (rows of sweeps.parquet: `file` the .bin relative to the root)."""
    for row in rows:
        path, stamp = root / str(row["file"]), int(row["stamp_ns"])
        try:
            counts, xyz, refl = sweep_points(path.read_bytes(), str(row["file"]))
        except FileNotFoundError as err:
            raise MissingDataError(f"{path}: indexed sweep {row['sweep']} is gone") from err
        yield Sweep(xyz, refl.astype(np.float32), np.full(counts.valid, stamp, np.int64), counts)
