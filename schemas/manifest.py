"""The JSON run manifest: what produced an output and which stage items are complete.

Stored at `<output_dir>/manifest.json`, written atomically (temp file + rename) with its
checksum sidecar (`schemas.atomic_io.checksum_path`). A manifest that does not match its
checksum or cannot be parsed is refused in one line (`ManifestDamaged`) naming the command
that rebuilds it: `m3gd verify` sets it aside (`set_aside`), the next run rebuilds it.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from schemas.atomic_io import check_file, checksum_path, write_text_atomic
from schemas.errors import DataError
from schemas.layout import OutputLayout
from schemas.stages import GEOMETRY
from schemas.versioning import check_version

MANIFEST_VERSION = 1
DAMAGED_SUFFIX = ".damaged"
"""A damaged manifest set aside is renamed `manifest.json.damaged`."""


class ManifestDamaged(DataError):
    """The run manifest does not match its checksum or cannot be parsed: one line naming the
    file and the command that rebuilds it; `detail` says what is wrong."""

    def __init__(self, path: Path, detail: str) -> None:
        self.path, self.detail = path, f"{path}: {detail}"
        super().__init__(f"{self.detail}; `m3gd verify {path.parent}` sets it aside, then "
                         "`m3gd run` rebuilds it (every stage is checked again)")


@dataclass(frozen=True)
class InputIdentity:
    """Identity of one input file: path, size in bytes, mtime in ns, optional sha256."""

    path: str
    size: int
    mtime_ns: int
    sha256: str | None = None

    @classmethod
    def of(cls, path: Path) -> InputIdentity:
        """Stat `path` (no hashing: size + mtime identify large bags cheaply)."""
        st = path.stat()
        return cls(str(path.resolve()), st.st_size, st.st_mtime_ns)


@dataclass
class StageRecord:
    """Completion of one stage: keys of finished items with their cache keys."""

    items: dict[str, str] = field(default_factory=dict)
    finished_unix_s: float | None = None


@dataclass
class RunManifest:
    """Everything needed to tell whether an output is current."""

    config_hash: str
    code_version: str
    packages: dict[str, str]
    inputs: list[InputIdentity] = field(default_factory=list)
    stages: dict[str, StageRecord] = field(default_factory=dict)
    checks: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    """Per recording: which plausibility check ran on which topic, its state and reject count
    (the rows of the recording's checks table, as its last ingest left them)."""
    version: int = MANIFEST_VERSION
    created_unix_s: float = field(default_factory=time.time)

    def is_done(self, stage: str, item: str, cache_key: str) -> bool:
        """True when `item` of `stage` finished with the same cache key."""
        rec = self.stages.get(stage)
        return rec is not None and rec.items.get(item) == cache_key

    def mark_done(self, stage: str, item: str, cache_key: str) -> None:
        """Record `item` of `stage` as finished with `cache_key`."""
        rec = self.stages.setdefault(stage, StageRecord())
        rec.items[item] = cache_key
        rec.finished_unix_s = time.time()

    def forget(self, stage: str) -> None:
        """Drop every completion record of `stage`."""
        self.stages.pop(stage, None)

    def geometry(self) -> dict[str, dict[str, dict[str, str]]]:
        """Per recording: the geometry verdict of each camera by image topic (`state`: ok,
        inconclusive or failed; `detail`: the reason and likely cause), from its `geometry`
        rows of `checks` (the verdict of a run that passed the geometry stage; a recording
        whose geometry failed unaccepted keeps its earlier entry: see its checks.parquet)."""
        return {rec: {str(r["topic"]): {"state": str(r["state"]), "detail": str(r["detail"])}
                      for r in rows if r.get("check") == GEOMETRY.name}
                for rec, rows in self.checks.items()
                if any(r.get("check") == GEOMETRY.name for r in rows)}

    def to_json(self) -> str:
        """Canonical JSON text."""
        return json.dumps(asdict(self), indent=1, sort_keys=True)

    @classmethod
    def from_json(cls, text: str, where: str = "<manifest>") -> RunManifest:
        """Parse JSON text; refuse an unknown version."""
        raw: dict[str, Any] = json.loads(text)
        check_version(raw.get("version"), MANIFEST_VERSION, "run manifest", where)
        raw["inputs"] = [InputIdentity(**i) for i in raw.get("inputs", [])]
        raw["stages"] = {k: StageRecord(**v) for k, v in raw.get("stages", {}).items()}
        return cls(**raw)


def write_manifest(manifest: RunManifest, out_dir: Path) -> Path:
    """Atomically write the manifest into `out_dir`; return its path. A write that fails (a
    full disk, a read-only folder) leaves the previous manifest in place and raises a
    one-line DataError naming the file and what to do."""
    path = OutputLayout(out_dir).manifest
    try:
        return write_text_atomic(path, manifest.to_json(), checksum=True)
    except OSError as err:
        raise DataError(f"{path}: the run manifest could not be written ("
                        f"{err.strerror or err}); the previous one is kept: free space or "
                        "make the folder writable, then run the same command again") from err


def read_manifest(out_dir: Path) -> RunManifest | None:
    """Read the manifest of `out_dir`, or None when there is none yet. ManifestDamaged when it
    does not match its checksum sidecar or cannot be parsed; DataError for another version."""
    path = OutputLayout(out_dir).manifest
    if not path.exists():
        return None
    why = check_file(path)
    if why is not None:
        raise ManifestDamaged(path, why)
    try:
        text = path.read_text()
        json.loads(text)
    except (ValueError, UnicodeDecodeError) as err:
        raise ManifestDamaged(path, f"not JSON ({err})") from err
    try:
        return RunManifest.from_json(text, str(path))
    except DataError:
        raise
    except (TypeError, KeyError, AttributeError, ValueError) as err:
        raise ManifestDamaged(path, f"not a run manifest ({type(err).__name__}: {err})"
                              ) from err


def set_aside(out_dir: Path) -> Path:
    """Rename a damaged manifest of `out_dir` to `manifest.json.damaged` (replacing an earlier
    one) and drop its sidecar: the next run starts a new one. Returns the new name."""
    path = OutputLayout(out_dir).manifest
    aside = path.with_name(path.name + DAMAGED_SUFFIX)
    path.replace(aside)
    checksum_path(path).unlink(missing_ok=True)
    return aside
