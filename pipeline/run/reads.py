"""What a stage reads from its output, declared by the stage (used on object storage).

On an `s3://` output an item runs in a scratch folder holding only the objects it reads
(`pipeline.run.remote`); the stage declares them beside its code (`StoreReads`, the
`store` field of `pipeline.run.stage.Stage`), so a new stage states its own reads. A stage
that declares nothing fetches every metadata object of the output (correct, slower).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from pipeline.run.keys import ItemKey
from schemas.layout import CACHE_DIRNAME, DONE_DIRNAME, INDEX_DIRNAME

ROOT_META = f"{CACHE_DIRNAME}/zarr.json"
"""The cache root's metadata object."""
RECORDING_GROUPS = (ROOT_META, f"{CACHE_DIRNAME}/{{r}}", f"{INDEX_DIRNAME}/{{r}}")
"""Prefixes of one recording's cache group and index ({r}: the item's recording)."""
CHUNK = re.compile(rf"^{CACHE_DIRNAME}/([^/]+)/([^/]+)/([^/]+)/c/(\d+)(/|$)")
"""A chunk (shard) object of a cache array: recording, camera, array, first grid index."""
MARK = re.compile(rf"^{DONE_DIRNAME}/([^/]+)/([^/]+)/[^/]+\.(\d+)\.json$")
"""A shard done-mark: recording, camera, shard."""


def _mine(key: ItemKey, rec: str, cam: str, index: int) -> bool:
    """Whether recording `rec`, camera `cam`, shard `index` are within the item `key`."""
    return key.recording in (None, rec) and key.camera in (None, cam) and (
        key.shard in (None, index))


@dataclass(frozen=True)
class Reads:
    """What an item of one stage fetches from the output: the prefixes to list ({r}, {c}:
    the item's recording and camera), and the cache arrays whose chunk objects it reads or
    rewrites. Chunks and done-marks are fetched only within the item's recording, camera and
    shard (those it has); chunks only of `arrays`. Rewritten arrays are fetched because
    tensorstore removes a chunk that a rewrite leaves all fill value: the item must see that
    file go to delete the object."""

    prefixes: tuple[str, ...]
    arrays: tuple[str, ...] = ()

    def of(self, key: ItemKey) -> list[str]:
        """The prefixes for the item `key`."""
        return [p.format(r=key.recording, c=key.camera) for p in self.prefixes]

    def keep(self, key: ItemKey, rel: str) -> bool:
        """Whether the item `key` needs the object `rel` (other metadata: always)."""
        if (mark := MARK.match(rel)) is not None:
            return _mine(key, mark.group(1), mark.group(2), int(mark.group(3)))
        if (hit := CHUNK.match(rel)) is not None:
            return hit.group(3) in self.arrays and _mine(key, hit.group(1), hit.group(2),
                                                         int(hit.group(4)))
        return True


ALL_METADATA = Reads(("",))
"""The whole output, chunks of no array: what an undeclared stage fetches."""


@dataclass(frozen=True)
class StoreReads:
    """A stage's reads: per item, per cross-recording item (None: as `item`), and what its
    `plan` reads on the driver (metadata prefixes; None: the plan reads no earlier output)."""

    item: Reads = ALL_METADATA
    cross: Reads | None = None
    plan: tuple[str, ...] | None = None

    def for_item(self, key: ItemKey) -> Reads:
        """What the item `key` fetches."""
        return self.cross if key.is_cross and self.cross is not None else self.item


UNDECLARED = StoreReads()
"""The reads of a stage that declares none: every metadata object, no chunk."""
