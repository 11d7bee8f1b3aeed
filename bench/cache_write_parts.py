"""Where the store's write time goes: the CPU seconds of each part of it, measured one part
at a time on the cache benchmark's data (all threads, `time.process_time`, median of a few
runs), per run and per GB of the bytes the part touches.

Parts: packing dense h (C_u, H, W views of cell-major memory, as the packet stage pools it) to
its occupied rows (`pack_rows`, per GB of dense h); the NaN/Inf guard (`all_finite`), CRC32C
(`store.raw_shard.crc32c`, the format's checksum, as the writer computes it) and the
`writev` of every stored chunk into fresh shard-sized files (syscalls and the page-cache
copy; no CRC) over the stored bytes (latents and packed rows); creating the group and its
arrays (zarr metadata, per run). Their sum beside the whole write shows what is left to
threads, Python and g (compressed, through tensorstore).
"""

from __future__ import annotations

import os
import shutil
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from schemas.cache_layout import GridSpec, GroupAttrs, latent_array, packet_arrays
from schemas.packed_cells import occupied_cells, pack_rows
from store.cache_store import ensure_array, ensure_group, open_root
from store.finite import all_finite
from store.raw_shard import crc32c
from store.shard_writer import writev_all

if TYPE_CHECKING:
    from bench.cache_data import CacheBenchSpec


def cpu_median(fn: Callable[[int], object], runs: int, before: Callable[[], None]) -> float:
    """Median CPU seconds of fn(run) over `runs` runs, `before()` untimed before each."""
    times = []
    for r in range(runs):
        before()
        cpu = time.process_time()
        fn(r)
        times.append(time.process_time() - cpu)
    return statistics.median(times)


def write_files(folder: Path, shards: list[list[np.ndarray]]) -> None:
    """One file per shard, its arrays written with `writev` (the store's syscall pattern)."""
    folder.mkdir(parents=True)
    for k, arrays in enumerate(shards):
        fd = os.open(folder / f"{k}", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            writev_all(fd, [a.reshape(-1).view(np.uint8).data for a in arrays])
        finally:
            os.close(fd)


def create_arrays(root: Path, spec: CacheBenchSpec) -> None:
    """The store's group and arrays, no data (what every write run sets up first)."""
    grid = GridSpec(spec.image_h, spec.image_w)
    group = ensure_group(open_root(root), GroupAttrs(
        "bench", "front", spec.views, spec.image_h, spec.image_w, 14, spec.shard_views))
    for s in [latent_array(grid, spec.channels, "float16"),
              *packet_arrays(grid, spec.point_channels, True)]:
        ensure_array(group, s, spec.views, spec.shard_views)


def part_figures(base: Path, data: dict[str, np.ndarray], spec: CacheBenchSpec,
                 runs: int = 3) -> dict[str, float]:
    """CPU seconds of each part of one store write (`write_part_cpu_s_<part>`) and per GB of
    the bytes it touches (`write_part_cpu_s_per_gb_<part>`)."""
    parts = [slice(s, s + spec.shard_views) for s in range(0, spec.views, spec.shard_views)]
    occupied = occupied_cells(data["g"])
    rows = [pack_rows(data["h"][p], occupied[p]) for p in parts]
    shards = [[*data["latents_l0"][p]] for p in parts] + rows
    stored = [a for shard in shards for a in shard]
    nbytes = sum(a.nbytes for a in stored)

    def clean() -> None:
        shutil.rmtree(base / "parts", ignore_errors=True)
        os.sync()

    timed: dict[str, tuple[float, float]] = {
        "pack": (cpu_median(lambda _: [pack_rows(data["h"][p], occupied[p]) for p in parts],
                            runs, clean), data["h"].nbytes),
        "finite": (cpu_median(lambda _: [all_finite(a) for a in stored], runs, clean), nbytes),
        "crc32c": (cpu_median(lambda _: [crc32c(a) for a in stored], runs, clean), nbytes),
        "writev": (cpu_median(lambda r: write_files(base / "parts" / f"{r}", shards), runs,
                              clean), nbytes),
        "setup": (cpu_median(lambda r: create_arrays(base / "parts" / f"{r}.zarr", spec),
                             runs, clean), 0.0),
    }
    clean()
    out = {f"write_part_cpu_s_{k}": s for k, (s, _) in timed.items()}
    out.update({f"write_part_cpu_s_per_gb_{k}": s / (n / 1e9)
                for k, (s, n) in timed.items() if n})
    out["write_parts_cpu_s_sum"] = sum(s for s, _ in timed.values())
    return out
