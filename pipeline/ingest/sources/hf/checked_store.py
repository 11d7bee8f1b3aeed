"""A read-only Zarr store over a foreign (Hugging Face) store folder that checks what it hands
to zarr-python: metadata files must be JSON, compressed chunks must pass their frame check
(`pipeline.ingest.sources.hf.frames`) against the buffer length and the array's chunk shape.

A failed check raises `DataError` naming the file, the array and the chunk, before any C
decoder sees the bytes: a truncated blosc chunk is then a reject of its rows instead of a
segmentation fault, and an invalid `.zarray` / `zarr.json` is one line naming the file
(DataError is permanent: the run does not retry it).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from zarr.abc.store import ByteRequest
from zarr.core.buffer import Buffer, BufferPrototype
from zarr.storage import LocalStore, WrapperStore

from pipeline.ingest.sources.hf.frames import CHECKS
from schemas.errors import DataError

METADATA = (".zarray", ".zgroup", ".zattrs", ".zmetadata", "zarr.json")


@dataclass(frozen=True)
class ChunkSpec:
    """What a chunk of one array must decode to: codec id (a key of CHECKS) and bytes."""

    codec: str
    nbytes: int | None


def _itemsize(dtype: Any) -> int | None:
    """Bytes per element of a v2 or v3 dtype description, None when not a plain dtype."""
    try:
        return int(np.dtype(dtype).itemsize)
    except (TypeError, ValueError):
        return None


def _codec_id(name: str) -> str:
    """'blosc' of 'blosc' and 'numcodecs.blosc'."""
    return name.rsplit(".", 1)[-1]


def spec_v2(meta: dict[str, Any]) -> ChunkSpec | None:
    """The check of a Zarr v2 array's chunks (None: no compressor this module checks)."""
    comp = meta.get("compressor") or {}
    codec = _codec_id(str(comp.get("id", "")))
    if codec not in CHECKS:
        return None
    item = _itemsize(meta.get("dtype"))
    plain = not meta.get("filters") and item is not None
    nbytes = int(np.prod(meta["chunks"])) * item if plain and item is not None else None
    return ChunkSpec(codec, nbytes)


def spec_v3(meta: dict[str, Any]) -> ChunkSpec | None:
    """The check of a Zarr v3 array's chunks: codecs [bytes, <checked codec>] only (sharded
    or other chains are read without a frame check)."""
    codecs = meta.get("codecs") or []
    names = [_codec_id(str(c.get("name", ""))) for c in codecs]
    if len(names) != 2 or names[0] != "bytes" or names[1] not in CHECKS:
        return None
    grid = meta.get("chunk_grid", {}).get("configuration", {}).get("chunk_shape")
    item = _itemsize(meta.get("data_type"))
    nbytes = int(np.prod(grid)) * item if grid is not None and item is not None else None
    return ChunkSpec(names[1], nbytes)


class CheckedStore(WrapperStore[LocalStore]):
    """A LocalStore whose reads are checked (see the module docstring)."""

    def __init__(self, store: LocalStore) -> None:
        super().__init__(store)
        self._nodes: dict[str, tuple[str, ChunkSpec | None]] = {}

    @classmethod
    def open_dir(cls, root: Path) -> CheckedStore:
        """A checked read-only store over the folder `root`."""
        return cls(LocalStore(root, read_only=True))

    @property
    def root(self) -> Path:
        """The store's folder."""
        return Path(self._store.root)

    async def get(self, key: str, prototype: BufferPrototype,
                  byte_range: ByteRequest | None = None) -> Buffer | None:  # fmt: skip
        """The bytes at `key`, checked when they are metadata or a whole compressed chunk."""
        buf = await self._store.get(key, prototype, byte_range)
        if buf is not None and byte_range is None:
            self.check(key, buf.to_bytes())
        return buf

    def check(self, key: str, data: bytes) -> None:
        """Raise DataError when `data` (the bytes at `key`) is not what its key promises."""
        name = key.rsplit("/", 1)[-1]
        if name in METADATA:
            try:
                json.loads(data)
            except ValueError as err:
                raise DataError(f"{self.root / key}: not valid JSON ({err}); the store's "
                                "metadata is damaged") from err  # fmt: skip
            return
        found = self._array_of(key)
        if found is None:
            return
        array, spec = found
        problem = CHECKS[spec.codec](data, spec.nbytes)
        if problem:
            chunk = key[len(array) + 1:] if array else key
            raise DataError(f"{self.root / key}: array {array or '/'} chunk {chunk}: "
                            f"{problem}")  # fmt: skip

    def _array_of(self, key: str) -> tuple[str, ChunkSpec] | None:
        """(array path, chunk check) of the checked array a chunk key lies in, else None."""
        parts = key.split("/")
        for i in range(len(parts) - 1, -1, -1):
            prefix = "/".join(parts[:i])
            if prefix not in self._nodes:
                self._nodes[prefix] = _node(self.root / prefix)
            kind, spec = self._nodes[prefix]
            if kind == "array":
                return (prefix, spec) if spec is not None else None
            if kind == "group":
                return None
        return None


def _node(folder: Path) -> tuple[str, ChunkSpec | None]:
    """('array', its chunk check or None), ('group', None) or ('', None) for a plain folder
    (invalid JSON in the metadata is a DataError naming the file)."""
    for name in (".zarray", "zarr.json", ".zgroup"):
        path = folder / name
        if not path.is_file():
            continue
        try:
            meta = json.loads(path.read_bytes())
        except ValueError as err:
            raise DataError(f"{path}: not valid JSON ({err}); the store's metadata is "
                            "damaged") from err  # fmt: skip
        if not isinstance(meta, dict):
            raise DataError(f"{path}: not a JSON object; the store's metadata is damaged")
        if name == ".zarray":
            return "array", spec_v2(meta)
        if name == "zarr.json" and meta.get("node_type") == "array":
            return "array", spec_v3(meta)
        return "group", None
    return "", None
