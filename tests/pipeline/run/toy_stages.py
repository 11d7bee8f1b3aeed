"""Tiny file-writing stages for runner tests (no project stage logic)."""

from __future__ import annotations

import hashlib
import os

from pipeline.run.keys import ItemKey
from pipeline.run.stage import Item, ItemResult, Stage
from schemas.config import M3GDConfig
from schemas.errors import DataError

RECORDINGS = ("rec_a", "rec_b", "rec_c")


def _key(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def plan_first(cfg: M3GDConfig) -> list[Item]:
    """Keyed like ingest: by the config and the recording's input identity (TOY_INPUT_<r>)."""
    return [Item(r, _key(r + str(cfg.select.max_abs_dt_s) + os.environ.get(f"TOY_INPUT_{r}", "")))
            for r in RECORDINGS]


def run_first(cfg: M3GDConfig, item: Item) -> ItemResult:
    out = cfg.output_dir / "first"
    out.mkdir(parents=True, exist_ok=True)
    rec = item.key.require_recording()
    if rec == os.environ.get("TOY_FAIL"):
        attempts = out / f"{item.key}.attempts"
        attempts.write_text(str(int(attempts.read_text()) + 1) if attempts.exists() else "1")
        kinds = {"data": DataError, "library": ValueError}
        kind = kinds.get(os.environ.get("TOY_FAIL_KIND", ""), RuntimeError)
        raise kind(f"injected failure in {item.key}")
    count = out / f"{item.key}.count"
    count.write_text(str(int(count.read_text()) + 1) if count.exists() else "1")
    (out / f"{item.key}.txt").write_text(f"{item.key}:{cfg.select.max_abs_dt_s}")
    return ItemResult(done=1)


def plan_second(cfg: M3GDConfig) -> list[Item]:
    return [Item(ItemKey(r, shard=0), _key(r + "second")) for r in RECORDINGS]


def run_second(cfg: M3GDConfig, item: Item) -> ItemResult:
    rec = item.key.require_recording()
    src = (cfg.output_dir / "first" / f"{rec}.txt").read_text()
    (cfg.output_dir / f"{rec}.second").write_text(src.upper())
    if rec == "rec_c":
        return ItemResult(done=1, rejected=1, warnings=["rec_c.bag: /topic: one message refused"])
    return ItemResult(done=1)


def plan_merge(cfg: M3GDConfig) -> list[Item]:
    return [Item(ItemKey.cross("merge"), _key("merge"))]


def run_merge(cfg: M3GDConfig, item: Item) -> ItemResult:
    """A cross-recording item (like the clip index): lists the recordings it saw."""
    seen = sorted(p.stem for p in cfg.output_dir.glob("*.second"))
    (cfg.output_dir / "merged.txt").write_text(",".join(seen))
    return ItemResult(done=len(seen))


STAGES = [
    Stage("first", (), plan_first, run_first),
    Stage("second", ("first",), plan_second, run_second),
    Stage("merge", ("second",), plan_merge, run_merge),
]
