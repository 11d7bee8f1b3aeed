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
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
import zarr

from pipeline.ingest.sources.hf.checked_store import CheckedStore
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


DECODE_ERRORS = (RuntimeError, ValueError, OSError)
"""What reading a damaged chunk raises: the CheckedStore's DataError (a ValueError), a
decoder's RuntimeError (blosc), an I/O error."""


class BadChunk(NamedTuple):
    """Rows first..last of `array` (data/<group>/<name>) lie in one chunk that cannot be read."""

    array: str
    first: int
    last: int
    detail: str


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
    _stamps: dict[str, tuple[I64, npt.NDArray[np.bool_], list[BadChunk]]] = field(
        default_factory=dict, repr=False)

    @classmethod
    def open(cls, mission_dir: Path) -> HfStore:
        """Open `<mission>/data` read-only, v2 or v3, through a CheckedStore (metadata and
        compressed chunks checked before decoding); MissingInputError naming the folder."""
        data = mission_dir / DATA_DIR
        version = zarr_version(data)
        if version is None:
            raise MissingInputError(f"{data}: not a Zarr store (no .zgroup or zarr.json); a "
                                    "Hugging Face mission folder holds data/ and images/")
        root = zarr.open_group(CheckedStore.open_dir(data), mode="r",
                               zarr_format=version)  # type: ignore[arg-type]
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
        """(int64 ns, ok) of a group's `timestamp` (N,), read once chunk by chunk (8 bytes a
        row); rows of a chunk that cannot be read are not ok (see `stamp_damage`)."""
        if group not in self._stamps:
            seconds, bad = self.read_chunked(group, "timestamp", np.float64)
            ns, ok = seconds_to_ns(seconds.reshape(seconds.shape[0], -1)[:, 0]
                                   if seconds.ndim > 1 else seconds)
            for chunk in bad:
                ok[chunk.first : chunk.last + 1] = False
            self._stamps[group] = ns, ok, bad
        ns, ok, _ = self._stamps[group]
        return ns, ok

    def stamp_damage(self, group: str, row: int) -> BadChunk | None:
        """The unreadable `timestamp` chunk holding `row`, if it is one."""
        self.stamps(group)
        return next((c for c in self._stamps[group][2] if c.first <= row <= c.last), None)

    def read_chunked(self, group: str, name: str, dtype: Any) -> tuple[npt.NDArray[Any],
                                                                      list[BadChunk]]:
        """Array `group/name` read chunk by chunk along axis 0 as `dtype`: (values, the chunks
        that cannot be read, whose rows are zeros)."""
        arr = self.array(group, name)
        n, step = int(arr.shape[0]), max(1, int(arr.chunks[0]))
        out = np.zeros(arr.shape, dtype)
        bad = []
        for start in range(0, n, step):
            stop = min(n, start + step)
            try:
                out[start:stop] = np.asarray(arr[start:stop], dtype)
            except DECODE_ERRORS as err:
                bad.append(self.bad_chunk(group, name, start, stop, err))
        return out, bad

    def bad_chunk(self, group: str, name: str, start: int, stop: int,
                  err: BaseException) -> BadChunk:  # fmt: skip
        """A BadChunk of rows [start, stop) of `group/name`, naming the cause."""
        where = self.where(group, name)
        return BadChunk(where, start, stop - 1, f"{where} rows {start}..{stop - 1} (one chunk) "
                        f"cannot be read: {type(err).__name__}: {err}")  # fmt: skip

    def image_path(self, group: str, row: int) -> Path:
        """`images/<group>/<row:06d>.jpeg` (PNG is not a camera image here)."""
        return self.mission_dir / IMAGES_DIR / group / f"{row:06d}.jpeg"
