"""Cache benchmark: the sharded Zarr store against one `.npy` file per view.

Writes (`bench.cache_write`): both formats write the same arrays from the same page-cache
state, neither with fsync, the order alternating; `write_vs_npy_per_view` is the ratio of
the medians over `write_rounds` rounds (> 1: the store is faster), with the spread of the
paired per-round ratios, and `write_cpu_vs_npy_per_view` the same for the CPU seconds of all
threads (the work without the waits for a core on a shared machine). Reads: the best of
`repeats` per clip, interleaved. Data:
N views of latents (C, H, W) float16 (dense, normal) and packets g (6, H, W)
float32 + h (C_u, H, W) float16 with a realistic fraction of occupied cells
(empty cells are zero, as in eq. 9-10), h in cell-major memory as the packet stage's pooling
leaves it. The .npy baseline stores h dense, channels-last as it lies; the store packs
it to occupied cells (`h_cells`) on write (timed). Clip reads hand h over packed (rows of the
occupied cells, placed by g), as the loader does; `clip_read_dense_h_vs_npy` adds unpacking
to dense channels-last. Reads are also measured against the floor of `cache_floor` (one
contiguous record per view in one file, one pread per view), warm and cold, against the
previous tensorstore reader, and against the same reader on a copy of the arrays without
chunk checksums (format 2's layout, `checksummed_read_cost_warm`), all in the same run.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from bench.cache_data import CacheBenchSpec, make_views
from bench.cache_write import write_figures, write_npy, write_zarr
from bench.cache_write_parts import part_figures
from bench.support.cache_floor import (
    OpenCounter,
    interleaved,
    read_floor_clip,
    timed_clips,
    write_floor,
)
from bench.support.no_checksums import strip_group
from schemas.cache_layout import H_CELLS, GridSpec, GroupAttrs, latent_array
from schemas.packed_cells import cell_counts, occupied_cells
from store.cache_io import read_clip, start_row_reads, ts_handle
from store.cache_store import ensure_array, ensure_group, open_root, write_region
from store.shard_reader import ShardReader


def clip_starts(spec: CacheBenchSpec) -> list[list[int]]:
    """Random clips: `clip_views` sorted frames within `clip_span` of one another."""
    rng = np.random.default_rng(spec.seed + 1)
    clips = []
    for _ in range(spec.clips):
        start = int(rng.integers(0, spec.views - spec.clip_span))
        frames = rng.choice(spec.clip_span, spec.clip_views, replace=False) + start
        clips.append(sorted(int(f) for f in frames))
    return clips


def read_npy_clip(root: Path, frames: list[int]) -> list[np.ndarray]:
    """One clip's views (latents, g, dense h channels-last (k, H, W, C_u), as `read_clip`
    gives it) from .npy files, stacked per array."""
    return [np.stack([np.load(root / name / f"{f:06d}.npy") for f in frames])
            for name in ("latents_l0", "g", "h")]


GROUP = ("bench", "front")
STORE_NAMES = ["latents_l0", "g", "h_rows"]


def zarr_clip_reader(root: Path, dense_h: bool = False, **options: Any
                     ) -> tuple[Any, ShardReader]:
    """`read(frames)` of the store the way the loader reads (`store.cache_io.read_clip`
    through one ShardReader kept for the run, `options` passed to it), and that reader."""
    group = root.joinpath(*GROUP)
    reader = ShardReader(**options)
    names = ["latents_l0", "g", "h" if dense_h else "h_rows"]
    return (lambda frames: read_clip(group, names, frames, reader)), reader


def read_clip_tensorstore(group: Path, frames: list[int]) -> dict[str, np.ndarray]:
    """The reader before issue 21: tensorstore futures on cached handles (it reopens each
    shard file and rereads its index per read), g first, then each view's h rows."""
    futures = {n: ts_handle(group / n)[frames].read() for n in ("latents_l0", "g")}
    g = np.asarray(futures.pop("g").result())
    rows = start_row_reads(group / H_CELLS, frames, cell_counts(occupied_cells(g)))
    return {"latents_l0": np.asarray(futures["latents_l0"].result()), "g": g,
            "h_rows": np.concatenate([np.asarray(r.result()) for r in rows])}


def same_clip(frames: list[int], clips: list[dict[str, np.ndarray]]) -> None:
    """Raise when the readers' arrays of one clip differ in any byte."""
    for name, ref in clips[0].items():
        for other in clips[1:]:
            if ref.shape != other[name].shape or ref.tobytes() != other[name].tobytes():
                raise AssertionError(f"clip {frames}: readers disagree on {name}")


def shard_files_touched(clip: list[int], spec: CacheBenchSpec) -> int:
    """Shard files a clip's views live in, over the store's three arrays."""
    return 3 * len({f // spec.shard_views for f in clip})


def read_clips_zarr_python(root: Path, clips: list[list[int]], names: list[str]) -> float:
    """Read every clip's views with zarr-python, one view at a time (its fastest path here)."""
    import zarr

    group = zarr.open_group(str(root), mode="r")["bench/front"]
    assert isinstance(group, zarr.Group)
    arrays = [group[name] for name in names]
    assert all(isinstance(a, zarr.Array) for a in arrays)
    t0 = time.perf_counter()
    for frames in clips:
        for arr in arrays:
            np.stack([np.asarray(arr[f]) for f in frames])  # type: ignore[index]
    return time.perf_counter() - t0


def tree_stats(root: Path, prefix: str = "") -> tuple[int, int]:
    """(file count, total bytes) of files under root whose relative path starts with prefix."""
    files = [p for p in root.rglob("*") if p.is_file() and str(p.relative_to(root)).startswith(
        prefix)]
    return len(files), sum(p.stat().st_size for p in files)


def zarr_bytes(root: Path, name: str, recording: str = "bench") -> int:
    """Bytes on disk of one Zarr array of the bench group."""
    return tree_stats(root / recording / "front" / name)[1]


def fp16_error(spec: CacheBenchSpec, base: Path) -> dict[str, float]:
    """Max relative error of float16 against float32 latents, and their bytes on disk.

    Both are stored as the cache stores latents (one view per chunk, sharded, raw codec).
    """
    rng = np.random.default_rng(spec.seed + 2)
    x = rng.normal(scale=3.0, size=(8, spec.channels, 16, 24)).astype(np.float32)
    y = x.astype(np.float16).astype(np.float32)
    big = np.abs(x) > 1e-3
    rel = np.abs(y - x)[big] / np.abs(x)[big]
    grid = GridSpec(16 * 14, 24 * 14)
    store = open_root(base / "fp16.zarr")
    group = ensure_group(store, GroupAttrs("fp16", "front", len(x), grid.image_h, grid.image_w,
                                           14, len(x)))
    size = {}
    for dtype in ("float16", "float32"):
        spec_d = replace(latent_array(grid, spec.channels, dtype), name=f"latents_{dtype}")
        arr = ensure_array(group, spec_d, len(x), len(x))
        write_region(arr, 0, x.astype(dtype))
        size[dtype] = zarr_bytes(base / "fp16.zarr", f"latents_{dtype}", "fp16")
    return {"fp16_max_rel_error": float(rel.max()),
            "fp16_size_ratio": size["float16"] / size["float32"]}


def forget(reader: ShardReader) -> bool:
    """Drop the reader's decoded small chunks (a cold read decodes them again); True."""
    reader.forget_chunks()
    return True


def read_figures(npy: Path, zroot: Path, base: Path, data: dict[str, np.ndarray],
                 spec: CacheBenchSpec, repeats: int) -> dict[str, float]:
    """Clip-read figures: store vs .npy, floor (warm and cold) and the tensorstore reader,
    interleaved clip by clip, fastest of `repeats` per clip (`cache_floor.interleaved`); cold
    reads drop the page cache (and the reader's decoded small chunks) before each clip (a
    quarter of the clips). Variants without the decoded-chunk cache (warm) and without the
    page-cache-miss prefetch (cold) show what each contributes."""
    clips = clip_starts(spec)
    floor = write_floor(base / "floor.bin", data)
    floor.open()
    store, reader = zarr_clip_reader(zroot)
    dense, _ = zarr_clip_reader(zroot, dense_h=True)
    no_cache, _ = zarr_clip_reader(zroot, chunk_cache_bytes=0)
    always, _ = zarr_clip_reader(zroot, verify="always")  # CRC32C on every read
    unchecked, _ = zarr_clip_reader(zroot, verify="off")  # what the CRC32C checks cost
    strip_group(zroot.joinpath(*GROUP), base / "no_crc.zarr" / GROUP[0] / GROUP[1],
                ["latents_l0", "g", H_CELLS])
    no_crc, _ = zarr_clip_reader(base / "no_crc.zarr")  # format 2's layout: no checksums
    no_prefetch, lazy = zarr_clip_reader(zroot, prefetch_clips=False)
    group = zroot.joinpath(*GROUP)
    with OpenCounter(zroot) as counted:
        store(clips[0])
        first = counted.opens
        timed_clips(store, clips[1:])
    assert reader.meta(group / H_CELLS) is not None  # nothing fell back to tensorstore
    readers = {"npy": lambda f: read_npy_clip(npy, f),
               "store": store, "dense": dense, "no_cache": no_cache, "always": always,
               "unchecked": unchecked, "no_crc": no_crc,
               "floor": lambda f: read_floor_clip(floor, f),
               "tensorstore": lambda f: read_clip_tensorstore(group, f)}
    for frames in clips:  # the compared readers return the same arrays (checked untimed)
        same_clip(frames, [readers[n](frames) for n in ("store", "floor", "tensorstore",
                                                        "no_crc")])
        same_clip(frames, [dense(frames), dict(zip(("latents_l0", "g", "h"),
                                                   read_npy_clip(npy, frames), strict=True))])
    warm = interleaved(readers, clips, repeats)
    cold_clips = clips[: max(1, len(clips) // 4)]
    cold = interleaved({  # nothing decoded kept either: every byte comes from the disk
        "store": lambda f: (forget(reader), store(f)),
        "no_prefetch": lambda f: (forget(lazy), no_prefetch(f)),
        "floor": readers["floor"], "tensorstore": readers["tensorstore"]},
        cold_clips, repeats, (zroot, floor.path))
    floor.close()
    reader.close()
    touched = [shard_files_touched(c, spec) for c in clips]
    return {
        "clip_read_vs_npy_per_view": warm["npy"] / warm["store"],
        "clip_read_dense_h_vs_npy": warm["npy"] / warm["dense"],
        "clip_read_over_floor_warm": warm["store"] / warm["floor"],
        "clip_read_over_floor_cold": cold["store"] / cold["floor"],
        "clip_read_over_floor_warm_no_chunk_cache": warm["no_cache"] / warm["floor"],
        "clip_read_over_floor_warm_verify_always": warm["always"] / warm["floor"],
        "clip_read_over_floor_warm_unchecked": warm["unchecked"] / warm["floor"],
        "crc_check_cost_warm": warm["store"] / warm["unchecked"] - 1.0,
        "checksummed_read_cost_warm": warm["store"] / warm["no_crc"] - 1.0,
        "crc_check_always_cost_warm": warm["always"] / warm["unchecked"] - 1.0,
        "clip_read_over_floor_cold_no_prefetch": cold["no_prefetch"] / cold["floor"],
        "tensorstore_read_over_floor_warm": warm["tensorstore"] / warm["floor"],
        "tensorstore_read_over_floor_cold": cold["tensorstore"] / cold["floor"],
        "files_opened_per_clip": counted.opens / len(clips),
        "files_opened_first_clip": float(first),
        "shard_files_touched_per_clip": float(np.mean(touched)),
        "shard_files_touched_first_clip": float(touched[0]),
        "zarr_clips_per_s": spec.clips / warm["store"],
        "floor_clips_per_s": spec.clips / warm["floor"],
        "npy_clips_per_s": spec.clips / warm["npy"],
        "zarr_cold_clips_per_s": len(cold_clips) / cold["store"],
        "floor_cold_clips_per_s": len(cold_clips) / cold["floor"],
    }


def run_cache_bench(spec: CacheBenchSpec | None = None, workdir: Path | None = None,
                    repeats: int = 3, write_rounds: int = 7) -> dict[str, float]:
    """Measure Zarr against .npy-per-view side by side: writes as medians of `write_rounds`
    alternating rounds (`bench.cache_write`), reads best of `repeats` per clip."""
    spec = spec or CacheBenchSpec()
    data = make_views(spec)
    base = Path(tempfile.mkdtemp(prefix="m3gd-bench-cache-", dir=workdir))
    try:
        out = write_figures(base, data, spec, write_rounds)
        out.update(part_figures(base, data, spec))  # where the store's write CPU goes
        npy, zroot = base / "npy", base / "store.zarr"  # the trees the reads use (untimed)
        write_npy(npy, data)
        write_zarr(zroot, data, spec)
        out.update(read_figures(npy, zroot, base, data, spec, repeats))
        clips = clip_starts(spec)
        r_zpy = read_clips_zarr_python(zroot, clips[: max(1, len(clips) // 4)],
                                       ["latents_l0", "g", H_CELLS])
        n_npy, _ = tree_stats(npy)
        n_zarr, _ = tree_stats(zroot)
        pk_npy = tree_stats(npy, "g")[1] + tree_stats(npy, "h")[1]
        pk_zarr = zarr_bytes(zroot, "g") + zarr_bytes(zroot, H_CELLS)
        out.update({
            "files_ratio": n_npy / n_zarr,
            "packet_bytes_ratio": pk_zarr / pk_npy,
            "latent_bytes_ratio": zarr_bytes(zroot, "latents_l0") / tree_stats(npy, "latents")[1],
            "zarr_write_mb_s": (sum(a.nbytes for a in data.values())
                                / out["write_store_wall_s_median"] / 1e6),
            "zarr_python_clips_per_s": max(1, len(clips) // 4) / r_zpy,
        })
        out.update(fp16_error(spec, base))
        return out
    finally:
        shutil.rmtree(base, ignore_errors=True)
