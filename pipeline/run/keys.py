"""Item keys: which data one item of a stage covers, and their one spelling."""

from __future__ import annotations

from dataclasses import dataclass

from schemas.errors import DataError

CROSS_PREFIX = "_"
"""Formatted keys of cross-recording items (latent normalization, clip index) start with this."""


@dataclass(frozen=True)
class ItemKey:
    """Which data an item covers; formatted (the manifest's and the log's spelling) as

    `<recording>`                  a whole recording (synth, ingest, select, packets, stats);
    `<recording>/<shard>`          one shard row of a recording (packets, `items: shard_row`);
    `<recording>/<camera>/<shard>` one shard of one camera's views (encode);
    `_<name>`                      a cross-recording item (`recording` None).
    """

    recording: str | None
    camera: str | None = None
    shard: int | None = None
    name: str | None = None

    def __post_init__(self) -> None:
        if (self.recording is None) == (self.name is None):
            raise DataError(f"item key needs a recording or a cross-recording name: {self!r}")
        if self.camera is not None and self.shard is None:
            raise DataError(f"item key with a camera needs a shard: {self!r}")
        for part in (self.recording, self.camera, self.name):
            if part is not None and (not part or "/" in part):
                raise DataError(f"item key part {part!r} is empty or holds '/'")
        if self.recording is not None and self.recording.startswith(CROSS_PREFIX):
            raise DataError(f"recording name {self.recording!r} starts with {CROSS_PREFIX!r}")
        if self.shard is not None and self.shard < 0:
            raise DataError(f"item key shard {self.shard} is negative")

    @classmethod
    def cross(cls, name: str) -> ItemKey:
        """The key of the cross-recording item `name` (formatted `_<name>`)."""
        return cls(None, name=name)

    @classmethod
    def parse(cls, text: str) -> ItemKey:
        """The key formatted as `text` (see the class docstring); DataError if malformed."""
        if text.startswith(CROSS_PREFIX):
            return cls.cross(text[len(CROSS_PREFIX):])
        parts = text.split("/")
        try:
            if len(parts) == 1:
                return cls(text)
            shard = parts[-1]
            canonical = shard.isascii() and shard.isdigit() and str(int(shard)) == shard
            if len(parts) in (2, 3) and canonical:
                return cls(parts[0], parts[1] if len(parts) == 3 else None, int(shard))
        except DataError as err:
            raise DataError(f"malformed item key {text!r}: {err}") from err
        raise DataError(f"malformed item key {text!r}")

    def format(self) -> str:
        """The key as one string: the inverse of `parse`."""
        if self.recording is None:
            return f"{CROSS_PREFIX}{self.name}"
        return "/".join(str(p) for p in (self.recording, self.camera, self.shard) if p is not None)

    def __str__(self) -> str:
        return self.format()

    def require_recording(self) -> str:
        """The recording of a per-recording item (DataError for a cross-recording one)."""
        if self.recording is None:
            raise DataError(f"item {self.format()!r} is not an item of one recording")
        return self.recording

    @property
    def is_cross(self) -> bool:
        """True for a cross-recording item (it reads every recording)."""
        return self.recording is None
