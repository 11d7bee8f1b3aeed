"""Write one recording of an output directory as a Rerun recording (`.rrd`).

Entity paths (timeline `stamp`, int64 ns as a Rerun timestamp):

- `world/trajectory` (static): odometry positions of the time range as one line strip;
- `world/robot`: the body pose (Transform3D) at every odometry stamp;
- `world/lidar`: each selected sweep in the world (odometry) frame at its sweep stamp, coloured
  by range from the sensor;
- `world/cameras/<cam>`: camera pose T_world_cam at the image stamp;
- `world/cameras/<cam>/image`: pinhole (cache K) and rectified image at the image stamp;
- `world/cameras/<cam>/image/lidar`: the selected sweep projected into the view (pixels),
  coloured by camera depth;
- `packets/<cam>/{validity,mean_depth_m,dtau_s}`: the packet grid channels as images;
- `stats/<cam>/dtau_s`: Δτ of each accepted view as a scalar series;
- `events/views`: rejected views (reason, Δτ) as text at their image stamp;
- `events/rejects`: rows of the rejects table (dropped messages) at their stamp.

Memory follows one shard row of views and one decoded sweep (`source.shard_rows`); each
selected sweep is decoded once per shard row that uses it and placed in the world once.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr

from packets.projection import project_points, transform_points
from pipeline.analysis.view import source
from pipeline.analysis.view.scene import (
    T_world_lidar,
    ViewPlan,
    depth_colors,
    packet_channels,
    plan_views,
    subsample,
)
from schemas.config import M3GDConfig

TIMELINE = "stamp"
APPLICATION_ID = "m3gd_view"


@dataclass(frozen=True)
class ViewOptions:
    """What to show. start_s / end_s: seconds after the recording's first image (None: open);
    max_views: at most this many views (the earliest), None for all; max_points: at most this
    many points per sweep and per projection (evenly strided), None for all; jpeg_quality:
    store images as JPEG of this quality (1-100) instead of raw pixels."""

    recording: str | None = None
    cameras: list[str] | None = None
    start_s: float | None = None
    end_s: float | None = None
    max_views: int | None = None
    max_points: int | None = None
    jpeg_quality: int | None = None


@dataclass
class ViewResult:
    """What a `.rrd` holds: counts of views, sweeps and events, its size, and what was skipped."""

    path: Path
    recording: str
    views: int = 0
    in_range: int = 0
    skipped: int = 0
    sweeps: int = 0
    events: int = 0
    bytes: int = 0
    duration_s: float = 0.0
    messages: list[str] = field(default_factory=list)


def stamp_time(rec: rr.RecordingStream, ns: int) -> None:
    """Set the `stamp` timeline of `rec` to int64 ns (exact: a datetime64 in ns)."""
    rec.set_time(TIMELINE, timestamp=np.datetime64(int(ns), "ns"))


def time_window(src: source.RecordingSource, opts: ViewOptions) -> tuple[int | None, int | None]:
    """[start_ns, end_ns] of the options (None: open), relative to the recording's first image
    (any camera, also when only some are shown)."""
    start = None if opts.start_s is None else src.t0_ns + round(opts.start_s * 1e9)
    end = None if opts.end_s is None else src.t0_ns + round(opts.end_s * 1e9)
    return start, end


def plan(src: source.RecordingSource, opts: ViewOptions) -> tuple[ViewPlan, int | None,
                                                                 int | None]:
    """The views to show and the time window [start_ns, end_ns] they were chosen in."""
    start, end = time_window(src, opts)
    return plan_views(src.stamps(), start, end, opts.max_views), start, end


def write_view(cfg: M3GDConfig, out: Path, opts: ViewOptions,
               on_views: Callable[[int, int], None] | None = None) -> ViewResult:
    """Write the `.rrd` of one recording to `out` (atomically: a temp file renamed at the end).

    `on_views(done, total)` is called after each shard row with the views logged so far
    (progress)."""
    src = source.open_recording(cfg, opts.recording, opts.cameras)
    view_plan, start, end = plan(src, opts)
    result = ViewResult(out, src.recording, in_range=view_plan.in_range,
                        skipped=view_plan.skipped)
    if view_plan.skipped:
        result.messages.append(_skip_message(src, view_plan, opts))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=f"m3gd-{src.recording}")
    rec.save(tmp)
    try:
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        _log_odometry(rec, src, start, end)
        result.events += _log_rejects(rec, src.recording, source.rejects(src, start, end))
        sweeps, logged = source.SweepReader(src), set[int]()
        done = 0
        for row in source.shard_rows(src, view_plan):
            result.events += _log_row(rec, cfg, row, sweeps, logged, opts)
            rec.flush()  # into the file before the next row is read: Rerun's buffers stay small
            done += sum(len(batch.frames) for batch in row)
            if on_views is not None:
                on_views(done, view_plan.shown)
        result.views, result.sweeps = view_plan.shown, len(logged)
    finally:
        rec.flush()
        rec.disconnect()
    os.replace(tmp, out)
    result.bytes = out.stat().st_size
    result.duration_s = _duration_s(src, view_plan)
    if not view_plan.shown:
        result.messages.append(f"{src.recording}: no view in the chosen time range")
    return result


def _duration_s(src: source.RecordingSource, view_plan: ViewPlan) -> float:
    """Seconds of recording the shown views span (first to last image stamp)."""
    shown = [s[view_plan.frames[c]] for c, s in src.stamps().items() if view_plan.frames[c].size]
    if not shown:
        return 0.0
    t = np.concatenate(shown)
    return float(int(t.max()) - int(t.min())) / 1e9


def _skip_message(src: source.RecordingSource, view_plan: ViewPlan, opts: ViewOptions) -> str:
    """One line saying which views --max-views left out and how to see them."""
    last = (view_plan.last_kept_ns or src.t0_ns) - src.t0_ns
    return (f"{src.recording}: --max-views {opts.max_views} kept the first {view_plan.shown} of "
            f"{view_plan.in_range} views in range (up to {last / 1e9:.3f} s after the first "
            f"image) and skipped {view_plan.skipped}; choose others with --start/--end or "
            "--camera")


def _log_odometry(rec: rr.RecordingStream, src: source.RecordingSource, start: int | None,
                  end: int | None) -> None:
    """The trajectory (static line strip) and the body pose at every odometry stamp."""
    stamps, pos, quat = source.odometry(src, start, end)
    if not stamps.size:
        return
    rec.log("world/trajectory", rr.LineStrips3D([pos.astype(np.float32)]), static=True)
    rec.send_columns("world/robot",
                     indexes=[rr.TimeColumn(TIMELINE, timestamp=stamps.astype("datetime64[ns]"))],
                     columns=rr.Transform3D.columns(translation=pos, quaternion=quat))


def _log_rejects(rec: rr.RecordingStream, recording: str, rows: Iterable[dict[str, Any]]) -> int:
    """Each dropped message of the rejects table as a warning at its stamp; returns the count."""
    n = 0
    for row in rows:
        stamp_time(rec, row["stamp_ns"])
        rec.log("events/rejects", rr.TextLog(
            f"{recording}: {row['reason']} on {row['topic']} in {row['file']}: {row['detail']}",
            level=rr.TextLogLevel.WARN))
        n += 1
    return n


def _log_row(rec: rr.RecordingStream, cfg: M3GDConfig, row: list[source.ViewBatch],
             sweeps: source.SweepReader, logged: set[int], opts: ViewOptions) -> int:
    """Every view of one shard row: images and rejected-view events first, then the selected
    sweeps in order, each decoded once and projected into every view (any camera) that selected
    it; a sweep is placed in the world once per file (`logged`). Returns the text events."""
    events = 0
    jobs: dict[int, list[tuple[source.ViewBatch, int]]] = {}
    for batch in row:
        sel = batch.camera.selection
        for i, frame in enumerate(batch.frames):
            events += _log_image(rec, batch, i, opts)
            if sel["ok"][frame]:
                jobs.setdefault(int(sel["sweep"][frame]), []).append((batch, i))
    for sweep, xyz in sweeps.decode(list(jobs)):
        for batch, i in jobs[sweep]:
            _log_packets(rec, cfg, batch, i, xyz, opts.max_points)
        if sweep in logged:  # already placed by an earlier shard row
            continue
        logged.add(sweep)
        batch, i = jobs[sweep][0]
        frame = batch.frames[i]
        stamp_time(rec, int(batch.camera.selection["sweep_stamp_ns"][frame]))
        _log_world_sweep(rec, xyz, T_world_lidar(batch.arrays["T_world_cam"][i],
                                                 batch.arrays["T_cam_lidar"][i]), opts.max_points)
    return events


def _log_image(rec: rr.RecordingStream, batch: source.ViewBatch, i: int,
               opts: ViewOptions) -> int:
    """Camera pose, pinhole and image of view i of a batch, and the event of a rejected view
    (returns 1 then, else 0)."""
    cam, sel, frame = batch.camera.camera, batch.camera.selection, batch.frames[i]
    a = {name: arr[i] for name, arr in batch.arrays.items()}
    base = f"world/cameras/{cam}"
    stamp_time(rec, int(a["stamp_ns"]))
    h, w = a["images"].shape[:2]
    rec.log(base, rr.Transform3D(translation=a["T_world_cam"][:3, 3],
                                 mat3x3=a["T_world_cam"][:3, :3]))
    rec.log(f"{base}/image", rr.Pinhole(image_from_camera=a["K"], resolution=[w, h],
                                        camera_xyz=rr.ViewCoordinates.RDF))
    image = rr.Image(a["images"])
    rec.log(f"{base}/image", image.compress(opts.jpeg_quality) if opts.jpeg_quality else image)
    if sel["ok"][frame]:
        return 0
    rec.log("events/views", rr.TextLog(
        f"{cam} frame {frame} rejected: {sel['reason'][frame]} "
        f"(dtau {sel['dtau_s'][frame] * 1e3:.1f} ms)", level=rr.TextLogLevel.WARN))
    return 1


def _log_packets(rec: rr.RecordingStream, cfg: M3GDConfig, batch: source.ViewBatch, i: int,
                 xyz: np.ndarray, max_points: int | None) -> None:
    """Δτ, packet grid channels and the projected sweep of accepted view i of a batch."""
    cam, sel, frame = batch.camera.camera, batch.camera.selection, batch.frames[i]
    a = {name: arr[i] for name, arr in batch.arrays.items()}
    stamp_time(rec, int(a["stamp_ns"]))
    rec.log(f"stats/{cam}/dtau_s", rr.Scalars(float(sel["dtau_s"][frame])))
    if "g" in a:
        for name, img in packet_channels(a["g"]).items():
            rec.log(f"packets/{cam}/{name}",
                    rr.DepthImage(img, meter=1.0) if name == "mean_depth_m" else rr.Image(img))
    _log_projection(rec, f"world/cameras/{cam}/image/lidar", xyz, a,
                    a["images"].shape[:2], cfg, max_points)


def _log_projection(rec: rr.RecordingStream, path: str, xyz: np.ndarray, a: dict[str, Any],
                    hw: tuple[int, int], cfg: M3GDConfig, max_points: int | None) -> None:
    """The sweep's points that land in the image, at their pixels, coloured by camera depth."""
    proj = project_points(xyz, a["K"], a["T_cam_lidar"], hw, min_depth_m=cfg.packets.min_depth_m)
    uv, depth = proj.uv[proj.valid], proj.depth[proj.valid]
    keep = subsample(len(uv), max_points)
    rec.log(path, rr.Points2D(uv[keep].astype(np.float32), colors=depth_colors(depth[keep]),
                              radii=1.0))


def _log_world_sweep(rec: rr.RecordingStream, xyz: np.ndarray, T_world_lidar_: np.ndarray,
                     max_points: int | None) -> None:
    """One sweep in the world frame, coloured by range from the sensor."""
    keep = subsample(len(xyz), max_points)
    pts = xyz[keep].astype(np.float64)
    world = transform_points(pts, T_world_lidar_)
    rec.log("world/lidar", rr.Points3D(world.astype(np.float32),
                                       colors=depth_colors(np.linalg.norm(pts, axis=1))))
