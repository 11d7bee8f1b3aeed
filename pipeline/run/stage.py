"""The contract every DAG stage follows: plan items on the driver, run each anywhere.

A stage's `plan` is cheap and runs in the driver process; it returns the items
(one per recording, or per recording-camera-shard) with the cache key that says
when an item's output is current. `run` does the work of one item; it is a plain
function of (config, item key) so it runs the same in-process or on a Dask worker.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.run.keys import ItemKey
from pipeline.run.reads import UNDECLARED, StoreReads
from schemas.config import M3GDConfig
from schemas.errors import DataError


@dataclass(frozen=True)
class Item:
    """One unit of work of a stage: its key and the cache key of its inputs.

    `key` may be given formatted (a str); it is parsed into an ItemKey.
    """

    key: ItemKey
    cache_key: str

    def __post_init__(self) -> None:
        if isinstance(self.key, str):
            object.__setattr__(self, "key", ItemKey.parse(self.key))


@dataclass
class ItemResult:
    """What one item did: counts of processed and rejected things, and details."""

    done: int = 0
    rejected: int = 0
    detail: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    """Problems the user should read (a damaged bag, a missing topic): logged by the runner."""


@dataclass(frozen=True)
class Stage:
    """A node of the stage graph."""

    name: str
    depends: tuple[str, ...]
    plan: Callable[[M3GDConfig], list[Item]]
    run: Callable[[M3GDConfig, Item], ItemResult]
    unit: str = "items"
    store: StoreReads = UNDECLARED
    """What its items and plan read from the output (fetched on object storage)."""
    resources: Callable[[M3GDConfig], dict[str, float]] | None = None
    """Dask worker resources each item needs (e.g. {"GPU": 1}); None: any worker."""
    outputs: Callable[[M3GDConfig, Item], list[Path]] | None = None
    """Table files a finished item wrote (local outputs): a done item one of whose files is
    missing or unreadable is redone (`unreadable_output`)."""


def unreadable_output(stage: Stage, cfg: M3GDConfig, item: Item) -> str | None:
    """Why a finished item of `stage` must be redone (a table it wrote is gone or cannot be
    parsed: a cut Parquet footer), or None."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    for path in stage.outputs(cfg, item) if stage.outputs else []:
        try:
            pq.read_metadata(path)
        except (OSError, pa.ArrowInvalid) as err:
            return f"{path}: {type(err).__name__}: {err}"
    return None


def downstream_of(stages: list[Stage], name: str) -> list[str]:
    """`name` and every stage that depends on it, transitively, in graph order."""
    names = {s.name for s in stages}
    if name not in names:
        raise DataError(f"unknown stage {name!r}; stages are {sorted(names)}")
    hit = {name}
    for stage in stages:
        if hit.intersection(stage.depends):
            hit.add(stage.name)
    return [s.name for s in stages if s.name in hit]


def ancestors(stages: list[Stage], name: str) -> set[str]:
    """Every stage `name` depends on, transitively (not `name` itself)."""
    by_name = {s.name: s for s in stages}
    found: set[str] = set()
    todo = list(by_name[name].depends)
    while todo:
        dep = todo.pop()
        if dep not in found:
            found.add(dep)
            todo.extend(by_name[dep].depends)
    return found


def topological(stages: list[Stage]) -> list[Stage]:
    """Stages ordered so that every stage follows its dependencies."""
    done: list[Stage] = []
    seen: set[str] = set()
    pending = list(stages)
    while pending:
        ready = [s for s in pending if set(s.depends) <= seen]
        if not ready:
            raise DataError(f"stage graph has a cycle among {[s.name for s in pending]}")
        for s in ready:
            done.append(s)
            seen.add(s.name)
            pending.remove(s)
    return done
