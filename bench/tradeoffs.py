"""`m3gd bench tradeoffs`: what each speed / size knob saves and what it costs in accuracy.

One run synthesizes recordings with ground truth (speed swing and turning, so Δτ matters),
ingests and selects them with a wide |Δτ| bound, and then measures every knob side by side on
the same views against the ground-truth cell depths (`packets.accuracy`):

- `select.max_abs_dt_s`: views kept and depth abs-rel of the kept views, per bound;
- odometry-chain correction vs static extrinsics (T_cam_lidar = T_cam_base T_base_lidar), and a
  controlled Δτ sweep (each view paired with its nearest sweep and the two on either side) that
  gives `absrel_per_100ms_dtau_at_1mps` with and without the chain;
- front-surface pooling: off, the fixed 0.5 m margin, margins relative to depth; border-cell
  abs-rel and the share of in-frustum points dropped;
- float16 vs float32: packet g (depth through 1/g[2]) and image latents (relative error, bytes);
- reduced vs full JPEG decode: ms per image and PSNR against the reference chain;
- points per sweep (subsampling 1/2, 1/4): point-encoder time, depth abs-rel, supported cells;
- the camera clock offset: depth abs-rel vs an injected offset, without and with
  `select.time_offset_s`, and the offset estimated from the data (`packets.time_offset`) against
  the injected truth.

Times are process CPU seconds measured in this run; ratios are against the baseline in the same
run (never absolute thresholds).
"""

from __future__ import annotations

import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from bench.measure import fastest
from bench.recording import Chain, Recording, SweepStore, prepare
from packets.accuracy import depth_errors, packet_depth, slope, support_depth
from packets.assemble import view_support
from packets.statistics import cell_depth_stats, explicit_channels
from packets.support import PATCH_PX, SupportSets, front_surface
from pipeline.analysis.accuracy import ViewTruth, strict_json, view_truths
from schemas.config import PacketsConfig, SelectConfig

F64 = npt.NDArray[np.float64]
BOUNDS_S: tuple[float, ...] = (0.02, 0.035, 0.05, 0.1, 0.2, 10.0)
MARGINS: tuple[tuple[float, float], ...] = ((0.5, 0.0), (1.0, 0.0), (0.1, 0.3), (0.1, 0.5),
                                            (0.1, 1.0), (0.1, 1.5), (0.1, 2.0), (0.1, 3.0))
"""Front-surface (margin_m, rel) candidates; (0.5, 0) is the fixed margin."""
DEFAULT_MARGIN = (PacketsConfig().front_margin_m, PacketsConfig().front_margin_rel)
SUBSAMPLE: tuple[int, ...] = (1, 2, 4)
OFFSETS_S: tuple[float, ...] = (0.0, 0.02, 0.05, 0.1)
TRAVEL_M = 0.1


def _cpu(fn: Callable[[], Any]) -> tuple[Any, float]:
    """(result, process CPU seconds) of fn()."""
    _, cpu, out = fastest(fn)
    return out, cpu


def _depth(xyz: npt.NDArray[Any], view: ViewTruth, T: F64) -> tuple[F64, SupportSets]:
    """(H, W) packet mean depth of a sweep in a view (NaN where empty) and its support sets."""
    hw = (view.ref.median.shape[0] * PATCH_PX, view.ref.median.shape[1] * PATCH_PX)
    sup = view_support(xyz, view.K_out, T, hw)
    return support_depth(sup.cell, sup.depth, sup.grid_hw), sup


@dataclass
class Pairs:
    """Packet and reference depths collected over views, per variant name."""

    pred: dict[str, list[F64]]
    ref: dict[str, list[F64]]
    border: dict[str, list[npt.NDArray[np.bool_]]]

    @classmethod
    def empty(cls) -> Pairs:
        """No views yet."""
        return cls({}, {}, {})

    def add(self, name: str, depth: F64, view: ViewTruth) -> None:
        """Add one view's (H, W) packet depth under `name`."""
        self.pred.setdefault(name, []).append(depth.ravel())
        self.ref.setdefault(name, []).append(view.ref.median.ravel())
        self.border.setdefault(name, []).append(view.ref.border.ravel())

    def errors(self, name: str, where: str = "all") -> dict[str, float | int]:
        """Error summary of a variant over all, border or interior cells."""
        p, r = np.concatenate(self.pred[name]), np.concatenate(self.ref[name])
        b = np.concatenate(self.border[name])
        sel = {"all": np.ones_like(b), "border": b, "interior": ~b}[where]
        return depth_errors(p[sel], r[sel]).as_dict()

    def absrel(self, name: str, where: str = "all") -> float:
        """Depth abs-rel of a variant."""
        return float(self.errors(name, where)["abs_rel"])

    def cells(self, name: str) -> int:
        """Cells with a packet depth in a variant."""
        return int(sum(np.isfinite(p).sum() for p in self.pred[name]))


@dataclass
class Tally:
    """Everything collected over the views of all recordings."""

    pairs: Pairs
    dtau: list[tuple[float, int]]  # (|Δτ| s, view number in pairs "base")
    dropped: dict[str, int]
    in_frustum: int = 0
    sweep_dtau: list[tuple[float, float, float]] | None = None  # (travel m, err chain, static)
    g: list[npt.NDArray[np.float32]] | None = None  # every view's g (6, H, W), for the bytes


def _view_absrel(depth: F64, view: ViewTruth) -> float:
    """Mean abs-rel of one view's cells (NaN if none)."""
    return float(depth_errors(depth, view.ref.median).abs_rel)


def evaluate_view(view: ViewTruth, store: SweepStore, chain: Chain, t: Tally) -> None:
    """All knob variants of one view, added to the tally."""
    xyz = store.xyz(view.sweep)
    base, sup = _depth(xyz, view, view.T_cam_lidar)
    t.dtau.append((abs(view.dtau_s), len(t.pairs.pred.get("base", []))))
    t.pairs.add("base", base, view)
    t.pairs.add("static", _depth(xyz, view, chain.static(view.camera))[0], view)
    t.in_frustum += int(sup.point_idx.size)
    for m, r in MARGINS:
        fs = front_surface(sup, m, r)
        name = f"front_{m:g}m_{r:g}rel"
        t.pairs.add(name, support_depth(fs.cell, fs.depth, fs.grid_hw), view)
        t.dropped[name] = t.dropped.get(name, 0) + fs.n_front_dropped
    stats = cell_depth_stats(sup.cell, sup.depth, sup.n_cells)
    g = explicit_channels(stats, view.dtau_s, sup.grid_hw)
    if t.g is not None:
        t.g.append(g)
    t.pairs.add("g_float32", packet_depth(g), view)
    t.pairs.add("g_float16", packet_depth(g.astype(np.float16)), view)
    for k in SUBSAMPLE[1:]:
        t.pairs.add(f"points_1_{k}", _depth(xyz[::k], view, view.T_cam_lidar)[0], view)


def dtau_sweep(view: ViewTruth, store: SweepStore, chain: Chain, t: Tally,
               time_offset_s: float) -> None:
    """The same view paired with sweeps nearest-2 .. nearest+2: error vs travel |Δτ| * speed."""
    image_ns = view.stamp_ns - round(time_offset_s * 1e9)
    for j in (-2, -1, 0, 1, 2):
        s = view.sweep + j
        if s not in store.rows:
            continue
        sweep_ns = int(store.rows[s]["stamp_ns"])
        T = chain.chain(view.camera, image_ns, sweep_ns)
        if T is None:
            continue
        travel = abs(sweep_ns - image_ns) / 1e9 * view.speed_mps
        xyz = store.xyz(s)
        err = _view_absrel(_depth(xyz, view, T)[0], view)
        err_static = _view_absrel(_depth(xyz, view, chain.static(view.camera))[0], view)
        assert t.sweep_dtau is not None
        t.sweep_dtau.append((travel, err, err_static))


def collect(recs: list[Recording], max_views: int, sweep_views: int) -> Tally:
    """Evaluate up to `max_views` views per recording (evenly spaced) and the Δτ sweep on
    `sweep_views` of them."""
    t = Tally(Pairs.empty(), [], {}, 0, [], [])
    for rec in recs:
        store, chain = SweepStore(rec), Chain.load(rec)
        views = list(view_truths(rec.cfg, rec.name))
        step = max(1, len(views) // max_views)
        for i, view in enumerate(views[::step]):
            evaluate_view(view, store, chain, t)
            if i % max(1, (len(views) // step) // max(sweep_views, 1)) == 0:
                dtau_sweep(view, store, chain, t, rec.cfg.select.time_offset_s)
    return t


def bound_rows(t: Tally) -> list[dict[str, float]]:
    """Per |Δτ| bound: share of views kept and depth abs-rel over the kept views' cells."""
    rows = []
    for b in BOUNDS_S:
        keep = [i for dt, i in t.dtau if dt <= b]
        p = [t.pairs.pred["base"][i] for i in keep]
        r = [t.pairs.ref["base"][i] for i in keep]
        err = depth_errors(np.concatenate(p), np.concatenate(r)) if keep else None
        rows.append({"max_abs_dt_s": b, "views_kept": len(keep) / max(len(t.dtau), 1),
                     "depth_absrel": err.abs_rel if err else float("nan")})
    return rows


def encoder_times(rec: Recording, sweeps: int = 2) -> dict[int, float]:
    """Point-encoder CPU seconds per sweep for each subsampling factor (same sweeps)."""
    from pipeline.stages.common import point_encoder

    enc = point_encoder(rec.cfg.encoders)
    store = SweepStore(rec)
    chosen = sorted(store.rows)[: sweeps]
    out = {}
    for k in SUBSAMPLE:
        pts = [store.xyz(s)[::k] for s in chosen]
        def encode_all(pts: list[np.ndarray] = pts) -> object:
            return [enc.encode(p, np.zeros(len(p), np.float32)) for p in pts]

        _, sec = _cpu(encode_all)
        out[k] = sec / len(chosen)
    return out


def latent_float16(rec: Recording, images: int = 4) -> dict[str, float]:
    """Image latents of a few rectified images: float16 relative L2 error and bytes ratio."""
    from bench.ingest_bench import recording_jpegs
    from pipeline.ingest.calib.camera import build_rectifier
    from pipeline.stages.common import image_encoder

    cam, jpegs = recording_jpegs(rec.mission, rec.cfg.ingest, images)
    rect = build_rectifier(cam, (rec.cfg.ingest.out_height, rec.cfg.ingest.out_width))
    imgs = np.stack([rect.apply(j, "tradeoffs") for j in jpegs])
    lat = np.asarray(image_encoder(rec.cfg.encoders).encode(imgs)[0], np.float32)
    half = lat.astype(np.float16).astype(np.float32)
    return {"latents_float16_rel_l2": float(np.linalg.norm(half - lat) / np.linalg.norm(lat)),
            "latents_float16_bytes_ratio": 0.5}


def jpeg_decode() -> dict[str, float]:
    """Reduced (default choice) vs full JPEG decode at GrandTour size: time ratio and PSNR."""
    from bench.ingest_bench import grandtour_choices

    rows = grandtour_choices()
    full = next(r for r in rows if r["reduction"] == 1 and r["fixed_point"])
    chosen = next(r for r in rows if r["default"])
    def num(row: dict[str, object], key: str) -> float:
        return float(row[key])  # type: ignore[arg-type]  # the table's numeric columns

    return {"jpeg_reduced_time_ratio": num(chosen, "ms_per_image") / num(full, "ms_per_image"),
            "jpeg_reduced_factor": num(chosen, "reduction"),
            "jpeg_reduced_psnr_db": num(chosen, "psnr_db"),
            "jpeg_full_psnr_db": num(full, "psnr_db")}


def clock_offset_study(work: Path, synth: dict[str, Any], max_views: int) -> list[dict[str, Any]]:
    """Depth abs-rel vs an injected camera clock offset: uncorrected, corrected with the known
    offset (`select.time_offset_s`), and corrected with the offset estimated from the data
    (`packets.time_offset`, edge alignment) without looking at the truth."""
    from bench.offset_estimate import estimate_offset

    rows = []
    for off in OFFSETS_S:
        rec = prepare(work / f"offset_{off:g}", "corridor",
                      {**synth, "cameras": ["front"], "camera_clock_offset_s": off})
        row: dict[str, Any] = {"offset_s": off}
        row["uncorrected"] = _absrel_with_offset(rec, 0.0, max_views)
        est = estimate_offset(rec)
        row["estimated_s"] = est["estimated_s"]
        row["corrected"] = _absrel_with_offset(rec, off, max_views)
        if np.isfinite(est["estimated_s"]):
            row["estimate_corrected"] = _absrel_with_offset(rec, est["estimated_s"], max_views)
        rows.append(row)
    return rows


def _absrel_with_offset(rec: Recording, offset_s: float, max_views: int) -> float:
    """Select again with `select.time_offset_s` = offset_s and return the base depth abs-rel."""
    from pipeline.select.views import select_views

    sel = SelectConfig(max_abs_dt_s=10.0, time_offset_s=offset_s)
    select_views(rec.index, sel, rec.cfg.ingest)
    again = Recording(rec.cfg.model_copy(update={"select": sel}), rec.name, rec.mission, rec.index)
    return collect([again], max_views, 0).pairs.absrel("base")


def knob_summary(t: Tally, enc: dict[int, float]) -> dict[str, Any]:
    """The trade table's keys from a tally and the encoder timings."""
    p = t.pairs
    out: dict[str, Any] = {
        "views": len(t.dtau), "cells": p.cells("base"),
        "depth_absrel": p.absrel("base"),
        "depth_absrel_interior": p.absrel("base", "interior"),
        "depth_absrel_border": p.absrel("base", "border"),
        "depth_errors": p.errors("base"),
        "max_abs_dt_s": bound_rows(t),
        "odometry_chain_off_depth_absrel": p.absrel("static"),
        "g_float16_depth_absrel": p.absrel("g_float16"),
        "g_float16_vs_float32_max_rel_depth": _max_rel(p, "g_float16", "g_float32"),
        "g_float16_bytes_ratio": g_bytes_ratio(t.g or []),
    }
    sweep = np.asarray(t.sweep_dtau or [], np.float64).reshape(-1, 3)
    out["absrel_per_100ms_dtau_at_1mps"] = slope(sweep[:, 0], sweep[:, 1]) * TRAVEL_M
    out["absrel_per_100ms_dtau_at_1mps_static"] = slope(sweep[:, 0], sweep[:, 2]) * TRAVEL_M
    out["front_surface"] = {
        name: {"margin_m": m, "rel": r, "depth_absrel": p.absrel(name),
               "depth_absrel_border": p.absrel(name, "border"),
               "depth_absrel_interior": p.absrel(name, "interior"),
               "dropped_share": t.dropped[name] / max(t.in_frustum, 1)}
        for m, r in MARGINS for name in [f"front_{m:g}m_{r:g}rel"]}
    fixed = out["front_surface"]["front_0.5m_0rel"]
    default = out["front_surface"][f"front_{DEFAULT_MARGIN[0]:g}m_{DEFAULT_MARGIN[1]:g}rel"]
    out["front_surface_off_depth_absrel_border"] = out["depth_absrel_border"]
    out["front_surface_fixed_depth_absrel_border"] = fixed["depth_absrel_border"]
    out["front_surface_fixed_dropped_share"] = fixed["dropped_share"]
    out["front_surface_relative_depth_absrel_border"] = default["depth_absrel_border"]
    out["front_surface_relative_dropped_share"] = default["dropped_share"]
    best = min(out["front_surface"].items(), key=lambda kv: kv[1]["depth_absrel_border"])
    out["front_surface_best"] = best[0]
    for k in SUBSAMPLE[1:]:
        out[f"points_1_{k}_depth_absrel"] = p.absrel(f"points_1_{k}")
        out[f"points_1_{k}_cells_ratio"] = p.cells(f"points_1_{k}") / max(p.cells("base"), 1)
        out[f"points_1_{k}_time_ratio"] = enc[k] / enc[1]
    out["point_encoder_s_per_sweep"] = enc[1]
    return out


def g_bytes_ratio(g: list[npt.NDArray[np.float32]]) -> float:
    """Stored bytes of g in float16 over float32, both zstd level 1 as the cache stores g."""
    from numcodecs import Zstd

    if not g:
        return float("nan")
    arr = np.stack(g)
    codec = Zstd(level=1)
    return len(codec.encode(arr.astype(np.float16))) / len(codec.encode(arr))


def _max_rel(p: Pairs, a: str, b: str) -> float:
    """Largest relative difference of two variants' cell depths."""
    x, y = np.concatenate(p.pred[a]), np.concatenate(p.pred[b])
    ok = np.isfinite(x) & np.isfinite(y)
    return float(np.max(np.abs(x[ok] - y[ok]) / y[ok])) if ok.any() else float("nan")


MOTION = {"speed_mps": 1.0, "speed_variation": 0.6, "speed_period_s": 4.0,
          "yaw_rate_max_rps": 1.0, "yaw_period_s": 3.0}
"""Synth motion of the bench: 0.4-1.6 m/s and turning at up to ~1 rad/s."""


def run_tradeoffs(workdir: Path | None = None, seconds: float = 4.0,
                  scenes: tuple[str, ...] = ("corridor", "warehouse"), max_views: int = 60,
                  sweep_views: int = 12, offsets: bool = True) -> dict[str, Any]:
    """The whole trade table (see the module docstring), as strict-JSON-ready data.

    The recordings go to a fresh temporary folder (under `workdir` if given), removed after.
    """
    work = Path(tempfile.mkdtemp(prefix="m3gd-bench-tradeoffs-", dir=workdir))
    try:
        out: dict[str, Any] = strict_json(
            _tradeoffs(work, seconds, scenes, max_views, sweep_views, offsets))
        return out
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _tradeoffs(work: Path, seconds: float, scenes: tuple[str, ...], max_views: int,
               sweep_views: int, offsets: bool) -> dict[str, Any]:
    """run_tradeoffs in a given folder."""
    synth = {"seconds": seconds, **MOTION}
    began = time.perf_counter()
    recs = [prepare(work / s, s, synth) for s in scenes]
    tally = collect(recs, max_views, sweep_views)
    out = knob_summary(tally, encoder_times(recs[0]))
    out.update(latent_float16(recs[0]))
    out.update(jpeg_decode())
    if offsets:
        off = clock_offset_study(work, {**synth, "seconds": min(seconds, 3.0)}, max_views)
        out["clock_offset"] = off
        out["clock_offset_100ms_depth_absrel"] = off[-1]["uncorrected"]
        out["clock_offset_100ms_corrected_depth_absrel"] = off[-1]["corrected"]
        out["clock_offset_estimate_max_error_s"] = max(
            abs(r["estimated_s"] - r["offset_s"]) for r in off)
    out["scenes"] = list(scenes)
    out["seconds_per_recording"] = seconds
    out["motion"] = MOTION
    out["wall_s"] = time.perf_counter() - began
    return out
