"""Writer of GrandTour's Hugging Face layout: one Zarr store per mission plus JPEG folders.

Layout (facts from the maintainers' public examples, `../shared/GRANDTOUR_HF.md`):
`<mission>/data/` is one Zarr store (v2 by default, as the release; v3 on request) with one
group per topic; `<mission>/images/<group>/NNNNNN.jpeg` holds camera image i, where i is the row
of the group's `timestamp`. Every topic group has `timestamp` (N,) float64 seconds since the
epoch and `sequence_id` (N,) (the ROS header seq) plus attributes `description`, `frame_id`,
`topic`. Rows are appended in blocks of one chunk, so memory holds one chunk of rows at most.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numcodecs
import numpy as np
import numpy.typing as npt
import zarr
from zarr.codecs import BloscCodec

from packets.poses import rot_to_quat

F64 = npt.NDArray[np.float64]
Columns = dict[str, tuple[tuple[int, ...], str]]
"""Array columns of a topic group: name -> (shape after the row axis, dtype)."""
DATA_DIR = "data"
IMAGES_DIR = "images"
CHUNK_ROWS = 16
"""Rows per chunk along time for every array (the release's own chunking is not stated)."""


def stamp_seconds(stamp_ns: int) -> float:
    """int64 ns -> float64 seconds since the epoch, rounded once (whole + fraction)."""
    return float(stamp_ns // 1_000_000_000) + (stamp_ns % 1_000_000_000) / 1e9


def image_name(row: int) -> str:
    """File name of camera image `row` (6 digits, zero-padded)."""
    return f"{row:06d}.jpeg"


def tf_entry(parent: str, T_child_parent: F64) -> dict[str, Any]:
    """A `tf` attribute entry {translation, rotation (w, x, y, z keyed), base_frame_id}.

    The release stores the transform that maps *parent* coordinates into the *child* frame
    (the reading of the maintainers' helper): callers pass T_child_parent.
    """
    T = np.asarray(T_child_parent, dtype=np.float64)
    q = rot_to_quat(T[:3, :3])
    t = T[:3, 3]
    return {
        "translation": {"x": float(t[0]), "y": float(t[1]), "z": float(t[2])},
        "rotation": {"w": float(q[3]), "x": float(q[0]), "y": float(q[1]), "z": float(q[2])},
        "base_frame_id": parent,
    }


def _compressors(zarr_format: int) -> Any:
    """Blosc/lz4 with byte shuffle, as numcodecs (v2) or a v3 codec."""
    if zarr_format == 2:
        return numcodecs.Blosc(cname="lz4", clevel=5, shuffle=numcodecs.Blosc.SHUFFLE)
    return BloscCodec(cname="lz4", clevel=5, shuffle="shuffle")


class RowTable:
    """The arrays of one topic group, grown along axis 0 one chunk of rows at a time."""

    def __init__(self, group: zarr.Group, columns: Columns,
                 zarr_format: int, chunk_rows: int = CHUNK_ROWS) -> None:  # fmt: skip
        """Create empty arrays (0, *tail) of `columns` {name: (tail shape, dtype)}."""
        self.arrays = {
            name: group.create_array(
                name, shape=(0, *tail), chunks=(chunk_rows, *tail), dtype=dtype,
                fill_value=0, compressors=_compressors(zarr_format),
            )
            for name, (tail, dtype) in columns.items()
        }
        self.chunk_rows = chunk_rows
        self._rows: dict[str, list[Any]] = {name: [] for name in columns}
        self.count = 0

    def append(self, **row: Any) -> int:
        """Add one row (a value per column); returns its row index."""
        for name, values in self._rows.items():
            values.append(row[name])
        self.count += 1
        if len(self._rows["timestamp"]) >= self.chunk_rows:
            self.flush()
        return self.count - 1

    def flush(self) -> None:
        """Write the buffered rows."""
        if not self._rows["timestamp"]:
            return
        for name, values in self._rows.items():
            arr = self.arrays[name]
            arr.append(np.asarray(values, dtype=arr.dtype).reshape(len(values), *arr.shape[1:]))
            values.clear()


class HfWriter:
    """One mission in the Hugging Face layout being written."""

    def __init__(self, mission_dir: Path, zarr_format: int = 2) -> None:
        """Create `<mission>/data` (a new Zarr store) and `<mission>/images`."""
        self.mission_dir = mission_dir
        self.zarr_format = zarr_format
        self.root = zarr.open_group(str(mission_dir / DATA_DIR), mode="w",
                                    zarr_format=zarr_format)  # type: ignore[arg-type]
        self.tables: dict[str, RowTable] = {}

    def topic(self, name: str, topic: str, frame_id: str, description: str,
              columns: Columns, **attrs: Any) -> RowTable:
        """A topic group with `timestamp`, `sequence_id` and `columns`, and its attributes."""
        group = self.root.create_group(name)
        group.attrs.update({"description": description, "frame_id": frame_id, "topic": topic,
                            **attrs})  # fmt: skip
        cols = {"timestamp": ((), "float64"), "sequence_id": ((), "uint32"), **columns}
        self.tables[name] = RowTable(group, cols, self.zarr_format)
        return self.tables[name]

    def set_attrs(self, name: str, **attrs: Any) -> None:
        """Add attributes to a group (created without arrays if new)."""
        group = self.root[name] if name in self.root else self.root.create_group(name)
        group.attrs.update(attrs)

    def image(self, group: str, row: int, jpeg: bytes) -> Path:
        """Write the JPEG of camera row `row` of `group`."""
        folder = self.mission_dir / IMAGES_DIR / group
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / image_name(row)
        path.write_bytes(jpeg)
        return path

    def close(self) -> None:
        """Flush every table."""
        for table in self.tables.values():
            table.flush()
