"""Atomic file writes: a reader sees the old file or the new one, never a partial one.

Tables and metadata files can be guarded by a checksum sidecar (`checksum=True`): a hidden
`.<name>.crc32c` beside the file (`checksum_path`), JSON (`CHECKSUM_KIND`, version
`CHECKSUM_VERSION`) holding the file's size, its CRC32C and the stage item that wrote it
(`written_by`), which `pipeline.run.checksums` checks, as zarr's `crc32c` codec guards each
cache chunk.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import BinaryIO

import google_crc32c

from schemas.layout import CACHE_DIRNAME, CLIPS_FILENAME, DONE_DIRNAME, STATS_DIRNAME


def write_atomic(path: Path, write: Callable[[BinaryIO], None], checksum: bool = False
                 ) -> Path:
    """Let `write` fill a process-private temporary beside `path`, then rename it over `path`.

    Creates the parent folder. A kill mid-write leaves at most a stray `.tmp` file, which
    the next write of the same path removes. checksum: then record its sidecar
    (`record_checksum`).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    for stale in path.parent.glob(f".{path.name}.*.tmp"):  # left by a killed writer
        stale.unlink(missing_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            write(f)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise with_path(err, path) from err
    os.replace(tmp, path)
    if checksum:
        record_checksum(path)
    return path


def record_checksum(path: Path) -> Path:
    """Write the sidecar of `path` as it is now (atomically); returns the sidecar. Called by
    the writer right after it renamed `path` into place: a kill in between leaves a sidecar
    that does not match, which `verify` and `run` treat as a damaged file (redone). A write
    that fails (a full disk) removes the old sidecar, which no longer describes the file,
    and raises. A file another stage's item wrote first (a table a later stage amends, a
    cache group's attributes) keeps that first writer: its redo rewrites the file whole
    and the amending stage, which depends on it, is redone after it."""
    size, crc = crc32c_of(path)
    stage, item = _WRITER.get() or (None, None)
    before = read_sidecar(checksum_path(path))
    if stage is not None and before is not None and before.stage not in (None, stage):
        stage, item = before.stage, before.item  # a later stage amends a table: its creator
    text = Checksum(path.name, size, crc, stage, item).to_json()
    try:
        return write_text_atomic(checksum_path(path), text)
    except OSError:
        checksum_path(path).unlink(missing_ok=True)
        raise


def with_path(err: OSError, path: Path) -> OSError:
    """`err` naming `path` when it names no file (a full disk raises `[Errno 28] No space left
    on device` from a write, without the file's name); else `err` itself."""
    if err.filename is not None or err.errno is None:
        return err
    return type(err)(err.errno, err.strerror, str(path))


def write_text_atomic(path: Path, text: str, checksum: bool = False) -> Path:
    """Write `text` (UTF-8) to `path` atomically (see `write_atomic`)."""
    data = text.encode()

    def write(f: BinaryIO) -> None:
        f.write(data)

    return write_atomic(path, write, checksum)


CHECKSUM_KIND = "m3gd-checksum"
CHECKSUM_VERSION = 1
"""Format of a checksum sidecar (`checksum_path`): JSON with this kind and version."""
CHECKSUM_SUFFIX = ".crc32c"
"""A sidecar's name: `.<file name><CHECKSUM_SUFFIX>`."""
_BLOCK = 1 << 20
_WRITER: ContextVar[tuple[str, str] | None] = ContextVar("m3gd_writer", default=None)
"""(stage, formatted item key) of the stage item running in this thread, recorded in the
checksum sidecars it writes (`written_by`)."""


@dataclass(frozen=True)
class Checksum:
    """What a sidecar records of its file: name, size, CRC32C, and the stage item that wrote
    it (None for a file written outside a stage: the run manifest)."""

    file: str
    size: int
    crc32c: str
    stage: str | None = None
    item: str | None = None

    def to_json(self) -> str:
        """Canonical JSON text (kind and version first)."""
        return json.dumps({"kind": CHECKSUM_KIND, "version": CHECKSUM_VERSION, **asdict(self)},
                          sort_keys=True)

    @classmethod
    def from_json(cls, text: str, where: str) -> Checksum:
        """Parse a sidecar; ValueError (one line naming `where`) for anything else."""
        try:
            raw = json.loads(text)
            if raw.pop("kind") != CHECKSUM_KIND or raw.pop("version") != CHECKSUM_VERSION:
                raise ValueError("another kind or version")
            return cls(**raw)
        except (ValueError, KeyError, TypeError, AttributeError) as err:
            raise ValueError(f"{where}: not an m3gd checksum sidecar ({err})") from err


def checksum_path(path: Path) -> Path:
    """The checksum sidecar of `path`: `.<name>.crc32c` beside it (hidden, so Parquet dataset
    readers ignore it); for a file inside the cache store (`cache.zarr/...`), at the same
    place under the done-marks folder beside the store (`cache_done/...`), which Zarr
    readers never list; for a file inside a table folder of the statistics
    (`stats/<table>/...`), at the same place under `stats/.<table>/`, beside the folder:
    polars reads every file of a folder it is given and refuses one of another kind."""
    parts = path.parts
    if CACHE_DIRNAME in parts[:-1]:
        k = len(parts) - 1 - parts[::-1].index(CACHE_DIRNAME)
        path = Path(*parts[:k], DONE_DIRNAME, *parts[k + 1:])
    elif _in_table_folder(path):
        path = path.parent.with_name(f".{path.parent.name}") / path.name
    return path.with_name(f".{path.name}{CHECKSUM_SUFFIX}")


def _in_table_folder(path: Path) -> bool:
    """Whether `path` is a file of a per-recording table folder, `stats/<table>/<rec>.parquet`
    (`schemas.tables.recording_part`; the clip index beside a root in a `stats` folder
    is not)."""
    parts = path.parts
    return (len(parts) >= 3 and parts[-3] == STATS_DIRNAME and path.suffix == ".parquet"
            and path.name != CLIPS_FILENAME)


def file_of(sidecar: Path) -> Path:
    """The file a sidecar (`checksum_path`) guards."""
    path = sidecar.with_name(sidecar.name[1:-len(CHECKSUM_SUFFIX)])
    parts = path.parts
    if DONE_DIRNAME in parts[:-1]:
        k = len(parts) - 1 - parts[::-1].index(DONE_DIRNAME)
        path = Path(*parts[:k], CACHE_DIRNAME, *parts[k + 1:])
    elif _in_table_folder(path) and path.parent.name.startswith("."):
        path = path.parent.with_name(path.parent.name[1:]) / path.name
    return path


def sidecar_text(name: str, data: bytes) -> str:
    """The sidecar of a file `name` holding `data`, written outside a stage (the manifest)."""
    return Checksum(name, len(data), f"{google_crc32c.value(data):08x}").to_json()


def crc32c_of(path: Path) -> tuple[int, str]:
    """(size, CRC32C as 8 hex digits) of the bytes of `path`, read in 1 MiB blocks."""
    crc, size = 0, 0
    with path.open("rb") as f:
        while block := f.read(_BLOCK):
            crc = google_crc32c.extend(crc, block)
            size += len(block)
    return size, f"{crc:08x}"


@contextmanager
def written_by(stage: str, item: str) -> Iterator[None]:
    """Within this block (this thread), sidecars record `stage` and `item` as their writer."""
    token = _WRITER.set((stage, item))
    try:
        yield
    finally:
        _WRITER.reset(token)


def check_file(path: Path) -> str | None:
    """Why `path` does not match its sidecar ('missing', 'cut: ...', 'CRC32C mismatch', an
    unreadable sidecar), or None when it matches or has no sidecar."""
    sidecar = checksum_path(path)
    try:
        want = Checksum.from_json(sidecar.read_text(), str(sidecar))
    except FileNotFoundError:
        return None
    except (OSError, ValueError, UnicodeDecodeError) as err:
        return f"its checksum sidecar cannot be read ({err})"
    try:
        size, crc = crc32c_of(path)
    except FileNotFoundError:
        return "missing"
    except OSError as err:
        return f"unreadable ({err.strerror or err})"
    if size != want.size:
        return f"cut or grown: {size} bytes, {want.size} written"
    if crc != want.crc32c:
        return f"CRC32C mismatch (stored {want.crc32c}, now {crc})"
    return None


def read_sidecar(sidecar: Path) -> Checksum | None:
    """The parsed sidecar, None when it cannot be read or parsed."""
    try:
        return Checksum.from_json(sidecar.read_text(), str(sidecar))
    except (OSError, ValueError, UnicodeDecodeError):
        return None
