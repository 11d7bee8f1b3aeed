"""`m3gd plot`: every analyst plot of an output directory, as PNG files under `<output>/plots`."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds

from model.train_log import FILENAME as TRAIN_LOG
from model.train_log import read_log
from pipeline.analysis import plots
from pipeline.analysis.align import cache_groups
from schemas.atomic_io import write_text_atomic
from schemas.cache_layout import H_CELLS
from schemas.layout import BENCH_DIRNAME, CACHE_DIRNAME, STATS_DIRNAME, OutputLayout
from schemas.packed_cells import occupied_cells
from store.cache_io import read_clip, read_views


def _table(output_dir: Path, name: str) -> pa.Table | None:
    """A merged statistics table (all recordings), or None when not written yet."""
    folder = OutputLayout(output_dir).stats / name
    if not any(folder.glob("*.parquet")):
        return None
    return ds.dataset(folder, format="parquet").to_table()


def pca_views(output_dir: Path, out: Path, count: int = 3) -> list[Path]:
    """Image | latent PCA | point-feature PCA for the first valid views of the first group."""
    written: list[Path] = []
    for group in cache_groups(output_dir)[:1]:
        path, attrs = group.path, group.attrs
        if not (path / H_CELLS).exists():
            continue
        valid = np.flatnonzero(read_views(path / "valid", list(range(attrs.n_views))))
        for frame in valid[np.linspace(0, len(valid) - 1, min(count, len(valid))).astype(int)]:
            a = read_clip(path, ["images", "latents_l0", "g", "h"], [int(frame)])
            written.append(plots.plot_pca_side_by_side(
                a["images"][0], a["latents_l0"][0], np.moveaxis(a["h"], -1, 1)[0],
                occupied_cells(a["g"])[0],
                out / f"pca_{attrs.recording}_{attrs.camera}_{int(frame):05d}.png"))
    return written


def save_bench(output_dir: Path, name: str, result: dict[str, Any]) -> Path:
    """Keep a benchmark's JSON result as `<output_dir>/bench/<name>.json` for the plots."""
    return write_text_atomic(OutputLayout(output_dir).bench / f"{name}.json",
                             json.dumps(result, default=str, indent=1))


def sampler_rows(result: dict[str, Any]) -> list[dict[str, float]]:
    """Flatten `m3gd bench sampler` JSON to rows K, M, latency_s, rel_l2_to_reference, and psnr
    / ssim (mean over eval targets, the same for every M) when a checkpoint was scored."""
    psnr = result.get("quality_psnr_ssim", {})
    rows = []
    for k, by_m in result["latency"].items():
        for m, cell in by_m.items():
            row = {"K": float(k), "M": float(m), "latency_s": float(cell["latency_s"]),
                   "rel_l2_to_reference": float(result["quality_rel_l2_to_reference"][k][m])}
            if k in psnr and "psnr_mean" in psnr[k]:
                row["psnr"] = float(psnr[k]["psnr_mean"])
            rows.append(row)
    return rows


def make_plots(output_dir: Path, dtau_bound_s: float | None = None,
               pca: bool = True) -> list[Path]:
    """Write every plot the output supports; return their paths.

    dtau_bound_s: the select stage's |Δτ| bound, drawn on the Δτ histograms; pca False
    skips the latent PCA views (they read cache chunks).
    """
    out = OutputLayout(output_dir).plots
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    views, cells = _table(output_dir, "view_stats"), _table(output_dir, "cell_stats")
    if views is not None:
        written.append(plots.plot_dtau_histograms(views, out / "dtau_hist.png",
                                                  bound_s=dtau_bound_s))
    accuracy = _table(output_dir, "accuracy")
    if accuracy is not None and accuracy.num_rows:
        from pipeline.analysis.accuracy import accuracy_plots

        written.extend(accuracy_plots(accuracy, out))
    if cells is not None:
        has_cache = (OutputLayout(output_dir).cache / "zarr.json").exists()
        groups = cache_groups(output_dir) if has_cache else []  # grid from the cache
        if groups:
            a = groups[0].attrs
            grid = (a.image_h // a.patch, a.image_w // a.patch)
            n_views = None if views is None else int(
                np.sum(np.asarray(views["reject_reason"].is_null())))
            written.append(plots.plot_occupancy_from_cells(cells, grid, out / "occupancy.png",
                                                           n_views))
        written.append(plots.plot_depth_histogram(cells["depth_mean_m"].to_numpy(),
                                                  out / "depth_hist.png", label="cell mean depth"))
    from pipeline.analysis.plots_consistency import consistency_plot

    consistency = consistency_plot(output_dir, out)  # `m3gd align --consistency`
    if consistency is not None:
        written.append(consistency)
    if pca and OutputLayout(output_dir).cache.exists():
        written.extend(pca_views(output_dir, out))
    sampler = OutputLayout(output_dir).bench / "sampler.json"
    if sampler.exists():
        rows = sampler_rows(json.loads(sampler.read_text()))
        quality = "psnr" if any("psnr" in r for r in rows) else "rel_l2_to_reference"
        written.append(plots.plot_speed_accuracy(rows, out / "speed_accuracy.png",
                                                 quality=quality))
    written.extend(plots.plot_training(read_log(log), out / f"train_{log.parent.name}.png",
                                       f"training run {log.parent}")
                   for log in sorted(OutputLayout(output_dir).train.glob(f"*/{TRAIN_LOG}")))
    science = OutputLayout(output_dir).bench / "science.json"
    if science.exists():  # `m3gd bench science`: loss curves and PSNR/SSIM vs CPU s/target
        from pipeline.analysis.plots_science import plot_science

        written.extend(plot_science(json.loads(science.read_text()), out))
    return written


def make_plots_on_store(location: Path | str, dtau_bound_s: float | None = None) -> list[str]:
    """The plots of an `s3://` output: its statistics, benchmark JSON and cache metadata (no
    chunk objects) are pulled to scratch, every plot that needs only those is drawn there
    (not the latent PCA views, which read chunks) and uploaded below `plots/`, each as one
    whole object. Returns the objects' URLs. StorageError (one line naming the URL) when
    the store cannot be reached."""
    from pipeline.run.remote import StoreOutput
    from pipeline.run.store_sync import push

    store = StoreOutput(location)
    store.check()
    with store.local_copy((STATS_DIRNAME, BENCH_DIRNAME, CACHE_DIRNAME)) as folder:
        rels = [p.relative_to(folder).as_posix()
                for p in make_plots(folder, dtau_bound_s, pca=False)]
        push(store.fs, store.url, folder, rels)
    return [store.url.url(rel) for rel in rels]
