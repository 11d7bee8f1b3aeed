"""The write half of the cache benchmark: the store against one `.npy` file per view.

Both formats write the same arrays (latents, g, h) to the same disk, neither fsyncs (the
store commits shards by rename, as `np.save` leaves its files to the kernel), and both are
timed from the same page-cache state: before each timed write every earlier tree is
removed and the dirty-page backlog written back (`os.sync`, outside the timing), so neither
pays for the other's writeback or finds less free page cache. The order alternates every
round. Figures are medians over the rounds with their spread (the paired ratio of each
round, min and max), wall clock and CPU seconds of all threads (`time.process_time`: the
work without the waits for a core on a shared machine), beside the 1-minute load average.

The `.npy` side pays what a user of one file per view pays (an open, a header, a close per
view and array) and checks nothing; the store writes fewer bytes (h packed to its occupied
cells, packing timed) in fewer files, with a CRC32C per chunk and the NaN/Inf guard.
"""

from __future__ import annotations

import os
import shutil
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from schemas.cache_layout import H_CELLS, GridSpec, GroupAttrs, latent_array, packet_arrays
from schemas.packed_cells import occupied_cells, pack_rows
from store.cache_store import ensure_array, ensure_group, open_root, write_packed, write_region
from store.shard_writer import ShardWriter

if TYPE_CHECKING:
    from bench.cache_data import CacheBenchSpec


def npy_view(view: np.ndarray) -> np.ndarray:
    """A view as a one-file-per-view user saves it: as it lies in memory (h's cells
    channels-last (H, W, C_u), its memory order; `np.save` of the channels-first view would
    gather it element by element)."""
    return view if view.flags.c_contiguous else np.moveaxis(view, 0, -1)


def write_npy(root: Path, data: dict[str, np.ndarray]) -> float:
    """Write one .npy per view and array; return seconds."""
    t0 = time.perf_counter()
    for name, arr in data.items():
        folder = root / name
        folder.mkdir(parents=True)
        for i in range(arr.shape[0]):
            np.save(folder / f"{i:06d}.npy", npy_view(arr[i]))
    return time.perf_counter() - t0


def write_zarr(root: Path, data: dict[str, np.ndarray], spec: CacheBenchSpec) -> float:
    """Write the same views as shard-aligned Zarr arrays (h packed, timed); return seconds."""
    grid = GridSpec(spec.image_h, spec.image_w)
    t0 = time.perf_counter()
    store = open_root(root)
    attrs = GroupAttrs("bench", "front", spec.views, spec.image_h, spec.image_w, 14,
                       spec.shard_views)
    group = ensure_group(store, attrs)
    specs = [latent_array(grid, spec.channels, "float16"),
             *packet_arrays(grid, spec.point_channels, True)]
    arrays = {s.name: ensure_array(group, s, spec.views, spec.shard_views) for s in specs}
    with ShardWriter() as writer:  # files written in the background while the next packs
        for start in range(0, spec.views, spec.shard_views):
            part = slice(start, start + spec.shard_views)
            write_region(arrays["latents_l0"], start, data["latents_l0"][part], writer)
            write_region(arrays["g"], start, data["g"][part], writer)
            occupied = occupied_cells(data["g"][part])  # packing is part of the write (timed)
            write_packed(arrays[H_CELLS], start, pack_rows(data["h"][part], occupied), writer)
    return time.perf_counter() - t0


@dataclass
class WriteRuns:
    """Seconds of every timed write, per format, in round order: wall clock and CPU."""

    wall: dict[str, list[float]] = field(default_factory=lambda: {"npy": [], "store": []})
    cpu: dict[str, list[float]] = field(default_factory=lambda: {"npy": [], "store": []})

    def figures(self, store: str = "store", prefix: str = "write") -> dict[str, float]:
        """Median ratios `.npy` / `store` (> 1: the store is faster) and their spread."""
        out: dict[str, float] = {}
        for clock, runs, label in ((self.wall, "wall", ""), (self.cpu, "cpu", "cpu_")):
            paired = [n / s for n, s in zip(clock["npy"], clock[store], strict=True)]
            out[f"{prefix}_{label}vs_npy_per_view"] = (statistics.median(clock["npy"])
                                                       / statistics.median(clock[store]))
            out[f"{prefix}_{label}vs_npy_paired_min"] = min(paired)
            out[f"{prefix}_{label}vs_npy_paired_max"] = max(paired)
            out[f"{prefix}_npy_{runs}_s_median"] = statistics.median(clock["npy"])
            out[f"{prefix}_store_{runs}_s_median"] = statistics.median(clock[store])
        out[f"{prefix}_rounds"] = float(len(self.wall["npy"]))
        return out


Writer = Callable[[Path], float]


def alternating_writes(base: Path, writers: dict[str, Writer], rounds: int) -> WriteRuns:
    """Time each writer `rounds` times after one untimed write each, the order rotated every
    round (two writers alternate), each from the same state: every earlier tree removed and
    `os.sync` before the timing; each tree removed after its write."""
    runs = WriteRuns({k: [] for k in writers}, {k: [] for k in writers})
    names = list(writers)
    for name in names:  # one untimed write each first: imports, thread pools, first pages
        writers[name](base / f"{name}-warm")
        shutil.rmtree(base / f"{name}-warm")
    for r in range(rounds):
        for name in names[r % len(names):] + names[:r % len(names)]:
            root = base / f"{name}{r}"
            os.sync()
            cpu = time.process_time()
            runs.wall[name].append(writers[name](root))
            runs.cpu[name].append(time.process_time() - cpu)
            shutil.rmtree(root)
    return runs


def write_figures(base: Path, data: dict[str, np.ndarray], spec: CacheBenchSpec,
                  rounds: int) -> dict[str, float]:
    """Write figures of `rounds` (>= 1) alternating rounds, with the load average."""
    load = os.getloadavg()[0]
    runs = alternating_writes(base, {"npy": lambda root: write_npy(root, data),
                                     "store": lambda root: write_zarr(root, data, spec)},
                              rounds)
    return {**runs.figures(), "load_avg_1min": load}
