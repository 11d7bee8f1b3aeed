"""Image sink of the ingest stage: rectified images into the cache, one shard at a time.

The number of images is known only at the end of the stream, so each camera's
arrays grow by one shard before each shard write (a metadata update) and are cut
to the final count at the end. Writes are whole shards, hence atomic per shard.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zarr

from schemas.cache_layout import GridSpec, GroupAttrs, image_arrays
from schemas.errors import DataError
from schemas.layout import OutputLayout
from store.cache_io import ts_handle
from store.cache_store import (
    drop_damaged_meta,
    ensure_array,
    open_root,
    set_group_attrs,
    write_region,
)


@dataclass
class _CameraBuffer:
    """Pending views of one camera: images (S, H, W, 3), stamps, intrinsics."""

    images: list[np.ndarray] = field(default_factory=list)
    stamps: list[int] = field(default_factory=list)
    Ks: list[np.ndarray] = field(default_factory=list)
    written: int = 0


class ImageCacheSink:
    """Collects `CameraImage`s per camera and writes them shard by shard into the cache."""

    def __init__(self, output_dir: Path, recording: str, grid: GridSpec, shard_views: int) -> None:
        self.path = OutputLayout(output_dir).cache
        # an existing cache is checked (format version) now; a new one is created on the first
        # image, so a recording that fails before any (no bags) leaves no empty cache behind
        self.root = open_root(self.path) if (self.path / "zarr.json").exists() else None
        self.recording, self.grid, self.shard = recording, grid, shard_views
        self.buffers: dict[str, _CameraBuffer] = {}
        self.groups: dict[str, zarr.Group] = {}

    def __call__(self, img: object) -> None:
        """Accept one image (a pipeline.ingest.core.stream.CameraImage) in frame order."""
        camera, frame = img.camera, img.frame  # type: ignore[attr-defined]
        buf = self.buffers.setdefault(camera, _CameraBuffer())
        if frame != buf.written + len(buf.images):
            raise DataError(f"{self.recording}/{camera}: frame {frame} out of order")
        buf.images.append(img.image)  # type: ignore[attr-defined]
        buf.stamps.append(img.stamp_ns)  # type: ignore[attr-defined]
        buf.Ks.append(img.K_out)  # type: ignore[attr-defined]
        if len(buf.images) == self.shard:
            self._flush(camera, buf)

    def _group(self, camera: str) -> zarr.Group:
        """The camera's group, created with zero views on first use."""
        if camera not in self.groups:
            attrs = GroupAttrs(self.recording, camera, 0, self.grid.image_h, self.grid.image_w,
                               self.grid.patch, self.shard)
            if self.root is None:
                self.root = open_root(self.path)
            drop_damaged_meta(self.root, f"{self.recording}/{camera}")
            group = self.root.require_group(f"{self.recording}/{camera}")
            for name in list(group.array_keys()):
                del group[name]  # a rerun of ingest rewrites the camera from scratch
            set_group_attrs(group, attrs.to_attrs())
            for spec in image_arrays(self.grid):
                ensure_array(group, spec, 0, self.shard)
            self.groups[camera] = group
        return self.groups[camera]

    def _flush(self, camera: str, buf: _CameraBuffer) -> None:
        """Grow the camera's arrays by the pending views and write them as one shard."""
        if not buf.images:
            return
        group = self._group(camera)
        start, n = buf.written, len(buf.images)
        data = {"images": np.stack(buf.images), "stamp_ns": np.asarray(buf.stamps, np.int64),
                "K": np.stack(buf.Ks).astype(np.float64)}
        for name, values in data.items():
            arr = group[name]
            assert isinstance(arr, zarr.Array)
            arr.resize((start + n, *arr.shape[1:]))
            ts_handle.cache_clear()
            write_region(arr, start, values)
        buf.written += n
        buf.images, buf.stamps, buf.Ks = [], [], []

    def close(self) -> dict[str, int]:
        """Write the last partial shards and set each group's view count; return counts."""
        counts = {}
        for camera, buf in self.buffers.items():
            self._flush(camera, buf)
            group = self._group(camera)
            attrs = dict(group.attrs)
            attrs["n_views"] = buf.written
            set_group_attrs(group, attrs)
            counts[camera] = buf.written
        return counts
