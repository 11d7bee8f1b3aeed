"""Opening a mission in GrandTour's Hugging Face layout: format detection, Zarr v2 or v3, groups.

A mission folder in that layout holds `data/` (one Zarr store, one group per topic) and
`images/<group>/NNNNNN.jpeg`. The release's store is Zarr v2 (`.zgroup`); a v3 store
(`zarr.json`) is read the same way. Stamps are float64 seconds since the epoch and are turned
into int64 ns here, rounding once (see `seconds_to_ns`).
"""

from __future__ import annotations

import difflib
import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import zarr

from schemas.errors import DataError, MissingInputError

DATA_DIR = "data"
IMAGES_DIR = "images"
FORMATS = ("rosbag", "hf-zarr")
I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]


def zarr_version(data_dir: Path) -> int | None:
    """2 (`.zgroup`), 3 (`zarr.json`) or None when `data_dir` is not a Zarr group."""
    if (data_dir / ".zgroup").is_file():
        return 2
    if (data_dir / "zarr.json").is_file():
        return 3
    return None


def detect_format(mission_dir: Path) -> str:
    """'hf-zarr' when the folder holds a Zarr store `data/`, else 'rosbag'."""
    return "hf-zarr" if zarr_version(mission_dir / DATA_DIR) is not None else "rosbag"


def resolve_format(mission_dir: Path, configured: str) -> tuple[str, bool]:
    """(format, detected?) of a mission folder; DataError when the configured one is absent."""
    found = detect_format(mission_dir)
    if configured == "auto":
        return found, True
    if configured == "hf-zarr" and found != "hf-zarr":
        raise DataError(f"{mission_dir}: ingest.format is hf-zarr but there is no Zarr store "
                         f"{mission_dir / DATA_DIR} (no .zgroup or zarr.json)")  # fmt: skip
    return configured, False


def seconds_to_ns(seconds: F64) -> tuple[I64, npt.NDArray[np.bool_]]:
    """(int64 ns, ok) from float64 seconds since the epoch; not ok: NaN, Inf or out of range.

    Whole seconds and the fraction are converted apart (the fraction exactly, the product
    rounded once): a float64 near 1.7e9 s resolves ~0.24 us, so the ns stamp is within
    0.12 us of the stamp the release was made from.
    """
    s = np.asarray(seconds, dtype=np.float64)
    ok = np.isfinite(s) & (np.abs(s) < 9e9)
    s = np.where(ok, s, 0.0)
    whole = np.floor(s)
    frac = np.rint((s - whole) * 1e9).astype(np.int64)
    return whole.astype(np.int64) * 1_000_000_000 + frac, ok


@dataclass
class HfStore:
    """An opened mission: its folder, the Zarr root group, and the store's Zarr format.

    Group names and opened arrays are kept (each open reads metadata files through
    zarr-python's I/O thread): open one HfStore per pass over a store that does not change.
    """

    mission_dir: Path
    root: zarr.Group
    version: int
    _arrays: dict[tuple[str, str], zarr.Array[Any]] = field(default_factory=dict, repr=False)

    @classmethod
    def open(cls, mission_dir: Path) -> HfStore:
        """Open `<mission>/data` read-only, v2 or v3; MissingInputError naming the folder."""
        data = mission_dir / DATA_DIR
        version = zarr_version(data)
        if version is None:
            raise MissingInputError(f"{data}: not a Zarr store (no .zgroup or zarr.json); a "
                                    "Hugging Face mission folder holds data/ and images/")
        root = zarr.open_group(str(data), mode="r", zarr_format=version)  # type: ignore[arg-type]
        return cls(mission_dir, root, version)

    @functools.cached_property
    def groups(self) -> list[str]:
        """Topic group names, sorted."""
        return sorted(self.root.group_keys())

    def has(self, name: str) -> bool:
        """Whether topic group `name` exists."""
        return name in self.groups

    def group(self, name: str, what: str) -> zarr.Group:
        """Topic group `name`; DataError naming the store, the group and close names."""
        if not self.has(name):
            raise DataError(self.missing(name, what))
        g = self.root[name]
        assert isinstance(g, zarr.Group)
        return g

    def missing(self, name: str, what: str) -> str:
        """The message for a missing topic group, with a did-you-mean."""
        close = difflib.get_close_matches(name, self.groups, n=2, cutoff=0.5)
        hint = f"; did you mean {' or '.join(close)}?" if close else ""
        return (f"{self.mission_dir / DATA_DIR} (Zarr v{self.version}): no {what} topic group "
                f"{name!r} (groups: {', '.join(self.groups) or 'none'}){hint}")  # fmt: skip

    def array(self, group: str, name: str) -> zarr.Array[Any]:
        """Array `group/name`; DataError naming it when absent."""
        if (group, name) in self._arrays:
            return self._arrays[group, name]
        g = self.root[group]
        assert isinstance(g, zarr.Group)
        try:
            a = g[name]
        except KeyError:
            a = None
        if not isinstance(a, zarr.Array):
            raise DataError(f"{self.where(group)}: no array {name!r} "
                             f"(arrays: {', '.join(sorted(g.array_keys()))})")  # fmt: skip
        self._arrays[group, name] = a
        return a

    def attrs(self, group: str) -> dict[str, Any]:
        """Attributes of a topic group."""
        return dict(self.root[group].attrs)

    def where(self, group: str, array: str | None = None) -> str:
        """'data/<group>[/<array>]' relative to the mission folder."""
        return f"{DATA_DIR}/{group}" + (f"/{array}" if array else "")

    def stamps(self, group: str) -> tuple[I64, npt.NDArray[np.bool_]]:
        """(int64 ns, ok) of a group's `timestamp` (N,), read whole (8 bytes a row)."""
        return seconds_to_ns(np.asarray(self.array(group, "timestamp")[:], np.float64).ravel())

    def image_path(self, group: str, row: int) -> Path:
        """`images/<group>/<row:06d>.jpeg` (PNG is not a camera image here)."""
        return self.mission_dir / IMAGES_DIR / group / f"{row:06d}.jpeg"
