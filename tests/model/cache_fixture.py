"""A tiny cache built in code (tests only): groups, arrays, clip index, latent norm."""

from __future__ import annotations

import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from schemas.cache_layout import (
    H_CELLS,
    GridSpec,
    GroupAttrs,
    LatentNorm,
    image_arrays,
    latent_array,
    packet_arrays,
    view_meta_arrays,
)
from schemas.packed_cells import occupied_cells, pack_rows
from schemas.tables import CLIPS, write_table
from store.cache_store import (
    ensure_array,
    ensure_group,
    open_root,
    write_packed,
    write_region,
)

GRID = GridSpec(28, 42)
C, CU, N, SHARD = 4, 3, 24, 8
Fill = Callable[[str, str, dict[str, np.ndarray]], None]
"""fill(recording, camera, arrays) may overwrite the arrays of one group in place before writing;
arrays["h"] is dense (N, C_u, H, W), packed on g[:, 0] into `h_cells` after the hook."""


def build_cache(out: Path, recordings: tuple[str, ...] = ("r0", "r1"),
                cameras: tuple[str, ...] = ("front", "left"), *,
                grid: GridSpec = GRID, channels: tuple[int, int] = (C, CU),
                fill: Fill | None = None,
                latent_norm: tuple[list[float], list[float]] | None = None,
                latent_dtype: str = "float32") -> None:
    """Write a small cache whose latent values encode (recording, camera, frame).

    grid, channels (C, C_u): array sizes; fill: optional hook that rewrites a group's arrays
    (name -> full (N, ...) array) in place, e.g. to plant packets and features;
    latent_norm: per-channel (mean, std) stored in the root attributes (default 0 and 1);
    latent_dtype: storage of latents_l0 (the pipeline's default is float16).
    """
    root = open_root(out / "cache.zarr")
    mean, std = latent_norm if latent_norm is not None else ([0.0] * channels[0],
                                                             [1.0] * channels[0])
    rows = []
    for r_i, rec in enumerate(recordings):
        for c_i, cam in enumerate(cameras):
            group = ensure_group(root, GroupAttrs(rec, cam, N, grid.image_h, grid.image_w, 14,
                                                  SHARD))
            specs = [*image_arrays(grid), *view_meta_arrays(),
                     latent_array(grid, channels[0], latent_dtype),
                     *packet_arrays(grid, channels[1], True)]
            arrays = {s.name: np.zeros(s.shape(N), s.dtype) for s in specs if s.name != H_CELLS}
            arrays["h"] = np.zeros((N, channels[1], grid.grid_h, grid.grid_w), np.float16)
            arrays["latents_l0"] += (np.arange(N) + 1000 * r_i + 100 * c_i)[:, None, None, None]
            arrays["T_world_cam"][:] = np.eye(4)
            arrays["T_world_cam"][:, 0, 3] = np.arange(N) * 0.3
            if fill is not None:
                fill(rec, cam, arrays)
            h_rows = pack_rows(arrays.pop("h"), occupied_cells(arrays["g"]))
            stored = {spec.name: ensure_array(group, spec, N, SHARD) for spec in specs}
            for name, arr in stored.items():
                for start in range(0, N, SHARD):
                    part = slice(start, start + SHARD)
                    if name == H_CELLS:
                        write_packed(arr, start, h_rows[part])
                    else:
                        write_region(arr, start, arrays[name][part])
            for f in range(0, N - 3, 2):
                rows.append({"clip_id": len(rows), "split": "train" if rec == "r0" else "eval",
                             "recording": rec, "camera": cam, "frames": [f, f + 1, f + 2, f + 3],
                             "is_target": [False, True, False, True],
                             "max_baseline_m": 0.9, "hard": False})
    table = pa.Table.from_pylist(rows, schema=CLIPS)
    write_table(table, CLIPS, out / "clips.parquet")
    set_latent_norm(out, list(mean), list(std))


def set_latent_norm(out: Path, mean: list[float], std: list[float]) -> None:
    """Store (mean, std) as the cache's `latent_norm`, recorded (as the stats stage does) over
    the valid views each group holds now; the cell count is not read by the model."""
    root = open_root(out / "cache.zarr")
    groups = {f"{rec}/{cam}": int(np.count_nonzero(root[f"{rec}/{cam}/valid"][:]))
              for rec, rec_group in root.groups() for cam, _ in rec_group.groups()}
    root.attrs["latent_norm"] = LatentNorm(mean, std, 0, groups).to_attrs()


def random_fill(rec: str, cam: str, arrays: dict[str, np.ndarray]) -> None:
    """A `Fill` of seeded random latents and g per recording and camera, fixed intrinsics."""
    rng = np.random.default_rng(zlib.crc32(f"{rec}/{cam}".encode()))
    arrays["K"][:] = [[20.0, 0, 20.5], [0, 20.0, 13.5], [0, 0, 1]]
    arrays["latents_l0"][:] = rng.standard_normal(arrays["latents_l0"].shape)
    arrays["g"][:] = rng.random(arrays["g"].shape)


def stamp_encoders(out: Path, recordings: tuple[str, ...] = ("r0", "r1"),
                   cameras: tuple[str, ...] = ("front", "left"), c: int = C, c_u: int = CU
                   ) -> None:
    """Write the encoder identities the encode stage records (a patch image encoder of `c`
    channels, an FPFH point encoder of `c_u`) into every group of the cache at `out`."""
    root = open_root(out / "cache.zarr")
    for rec in recordings:
        for cam in cameras:
            root[f"{rec}/{cam}"].attrs.update({
                "image_encoder": {"name": "patch", "version": "1", "weights_hash": "x",
                                  "pretrained": False, "channels": c},
                "point_encoder": {"name": "fpfh", "version": "1", "weights_hash": "y",
                                  "pretrained": False, "channels": c_u}})


def random_cache(factory: Any) -> Path:
    """A new cache (two recordings of `build_cache`) filled by `random_fill`, in a fresh
    folder of the pytest `tmp_path_factory` `factory`."""
    out: Path = factory.mktemp("cache")
    build_cache(out, fill=random_fill)
    return out


def tiny_net() -> Any:
    """The model tests' small network on this cache: geom_only packets, patch 1, adapter
    hidden width 16 (a `model.net.NetConfig`)."""
    from model.net import NetConfig

    return NetConfig(c=C, c_u=CU, grid_hw=(GRID.grid_h, GRID.grid_w),
                     image_hw=(GRID.image_h, GRID.image_w), mode="geom_only", patch=1,
                     adapter_hidden=16)
