"""The repair loop of `m3gd bench fuzz`: damage a finished output, verify, rerun, verify.

A tiny synthetic recording is run through every stage once (the clean output). Each repair
round copies the clean output, flips one bit in one stored chunk of one cache array (every
array kind of `schemas.cache_layout` in turn), runs `verify` (which must name the chunk and
forget what rewrites it), reruns the stage graph, and verifies again. Counted (goal 0 each):

- `repair_not_identical`: rounds whose output is not byte-identical to the clean one (every
  file but the manifest's times; the manifest's finished items compared as a table);
- `arrays_lost_by_repair`: arrays of the clean cache missing after the round;
- `repair_not_detected` / `repair_still_damaged`: a flip verify did not find / found again.

Config changes: for each of `CONFIG_CHANGES`, the clean output is rerun with the change and
compared with a fresh run of the changed config; `stale_derived_after_config_change` counts
the files (cache, done-marks, statistics, latent normalization, clip index) that differ.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from schemas.cache_layout import layout_arrays
from schemas.config import M3GDConfig, parse_config
from store.raw_shard import MISSING
from store.shard_layout import ArrayMeta, index_pairs

RECORDING = "m_repair"
GROUP = f"{RECORDING}/front"
CONFIG_CHANGES: dict[str, dict[str, Any]] = {
    "encoders.image_channels": {"encoders": {"image_channels": 32}},
    "cache.shard_views": {"cache": {"shard_views": 8}},
    "image_channels+shard_views": {"encoders": {"image_channels": 32},
                                   "cache": {"shard_views": 8}},
    "packets.mode": {"packets": {"mode": "geom_only"}},
}
"""Config changes applied to a finished output (nested updates of the raw config)."""


def raw_config(out: Path, mission: Path) -> dict[str, Any]:
    """The raw config of the tiny run of `mission` into `out` (4 views per shard)."""
    return {"output_dir": str(out),
            "ingest": {"recordings": [str(mission)], "cameras": ["front"], "out_height": 112,
                       "out_width": 168},
            "encoders": {"image_channels": 588, "point_channels": 16},
            "cache": {"shard_views": 4}, "dag": {"retries": 0, "executor": "local"},
            "clips": {"eval_clips_per_recording": 2}}


def _merged(raw: dict[str, Any], update: dict[str, Any]) -> dict[str, Any]:
    """`raw` with the nested `update` applied."""
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in raw.items()}
    for section, values in update.items():
        out[section] = {**out.get(section, {}), **values}
    return out


def make_recording(root: Path, seconds: float = 1.2) -> Path:
    """The tiny synthetic recording (front camera; written once per `root`)."""
    from pipeline.synth.api import synthesize
    from schemas.config import SynthConfig

    mission = root / RECORDING
    if not (mission / "groundtruth" / "faults.json").exists():
        synthesize(root, SynthConfig(seconds=seconds, image_width=192, image_height=128,
                                     points_per_sweep=1024, cameras=["front"],
                                     depth_maps=False), "corridor", mission=RECORDING)
    return mission


def run_all(cfg: M3GDConfig) -> list[str]:
    """Run every stage in-process under the run policy (`dags.run.run_graph`: preflight, the
    output lock); the failed items' lines."""
    from dags.run import run_graph

    return [f"{stage} {key}: {err}" for stage, key, err in run_graph(cfg).failed]


def verify(out: Path) -> tuple[Any, list[str]]:
    """`m3gd verify`'s check and invalidation of the output `out`: (report, forgotten)."""
    from dags.run import verify_cache

    report, forgotten = verify_cache(out)
    return report, list(forgotten)


def stored_chunks(folder: Path) -> list[tuple[Path, int, int]]:
    """(file, byte offset, bytes) of every stored chunk (data and CRC32C) of the array in
    `folder`."""
    meta = ArrayMeta.parse(json.loads((folder / "zarr.json").read_text()))
    assert meta is not None, folder
    out = []
    for shard in range(-(-meta.shape[0] // meta.file_views)):
        path = folder.joinpath("c", str(shard), *["0"] * (len(meta.shape) - 1))
        if not path.is_file():
            continue
        data = path.read_bytes()
        if not meta.sharded:
            out.append((path, 0, len(data)))
            continue
        n = int(np.prod([s // c for s, c in zip((meta.file_views, *meta.view_shape),
                                                 meta.chunk, strict=True)]))
        out += [(path, int(o), int(b)) for o, b in index_pairs(data, n).tolist()
                if o != int(MISSING)]
    return out


def flip_bit(path: Path, offset: int) -> None:
    """Flip the lowest bit of byte `offset` of `path`."""
    data = bytearray(path.read_bytes())
    data[offset] ^= 1
    path.write_bytes(bytes(data))


def digests(out: Path, manifest_items: bool = True) -> dict[str, str]:
    """sha256 of every file of an output (relative path -> digest), the manifest's finished
    items in place of the manifest and its checksum (its times differ from run to run; left out with
    `manifest_items` False: items an earlier config planned stay listed, unused)."""
    found = {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
             for p in sorted(out.rglob("*")) if p.is_file()
             and p.name not in ("manifest.json", ".manifest.json.crc32c")
             and not p.name.endswith(".lock")}  # lock files: empty, not outputs
    if not manifest_items:
        return found
    manifest = json.loads((out / "manifest.json").read_text())
    items = {s: r.get("items") for s, r in manifest.get("stages", {}).items()}
    found["manifest.json:items"] = hashlib.sha256(json.dumps(items, sort_keys=True)
                                                  .encode()).hexdigest()
    return found


def differing(a: dict[str, str], b: dict[str, str]) -> list[str]:
    """Files present in one digest table only, or with different bytes."""
    return sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))


def arrays_of(out: Path) -> set[str]:
    """`<group>/<array>` of every array of the output's cache."""
    cache = out / "cache.zarr"
    return {str(p.parent.relative_to(cache)) for p in cache.glob("*/*/*/zarr.json")}


@dataclass
class Round:
    """One repair round: which chunk was flipped and how the loop ended."""

    array: str
    chunk: str
    detected: bool
    still_damaged: bool
    not_identical: list[str]
    lost: list[str]
    failed: list[str]


def repair_round(clean: Path, case: Path, raw: dict[str, Any], array: str,
                 pick: int) -> Round:
    """Copy `clean` to `case`, flip one bit of stored chunk `pick` (modulo their count) of
    `array` of the recording's group, verify, rerun, verify, compare with `clean`."""
    shutil.rmtree(case, ignore_errors=True)
    shutil.copytree(clean, case)
    chunks = stored_chunks(case / "cache.zarr" / GROUP / array)
    path, offset, nbytes = chunks[pick % len(chunks)]
    flip_bit(path, offset + (pick * 7919) % nbytes)
    where = f"{path.relative_to(case)}@{offset}"
    report, _ = verify(case)
    failed = run_all(parse_config({**raw, "output_dir": str(case)}))
    again, _ = verify(case)
    return Round(array, where, report.damaged, again.damaged,
                 differing(digests(clean), digests(case)),
                 sorted(arrays_of(clean) - arrays_of(case)), failed)


def array_kinds() -> list[str]:
    """Every array kind a cache group holds (latents at level 0)."""
    return [s.name for s in layout_arrays()]


def rounds(rng: np.random.Generator, n: int) -> Iterator[tuple[str, int]]:
    """(array, chunk pick) for `n` rounds: every array kind in turn, random chunks."""
    kinds = array_kinds()
    for k in range(n):
        yield kinds[k % len(kinds)], int(rng.integers(0, 2**31))


def run_repair(work: Path, n_rounds: int | None = None, seed: int = 0,
               changes: dict[str, dict[str, Any]] | None = None) -> dict[str, Any]:
    """The repair figures: `n_rounds` rounds (default: one per array kind) and the config
    changes (default `CONFIG_CHANGES`)."""
    mission = make_recording(work / "recordings")
    raw = raw_config(work / "clean", mission)
    shutil.rmtree(work / "clean", ignore_errors=True)
    failed = run_all(parse_config(raw))
    if failed:
        raise RuntimeError(f"the clean repair run failed: {failed[0]}")
    rng = np.random.default_rng(seed)
    done = [repair_round(work / "clean", work / "case", raw, array, pick)
            for array, pick in rounds(rng, n_rounds or len(array_kinds()))]
    stale = stale_after_changes(work, raw, changes or CONFIG_CHANGES)
    return {
        "repair_rounds": len(done),
        "repair_not_detected": sum(not r.detected for r in done),
        "repair_still_damaged": sum(r.still_damaged for r in done),
        "repair_not_identical": sum(bool(r.not_identical) for r in done),
        "arrays_lost_by_repair": sum(len(r.lost) for r in done),
        "repair_failed_items": sum(len(r.failed) for r in done),
        "stale_derived_after_config_change": sum(len(v) for v in stale.values()),
        "config_changes": sorted(stale),
        "repair_failures": [{"array": r.array, "chunk": r.chunk, "differ": r.not_identical[:5],
                             "lost": r.lost, "failed": r.failed[:2]}
                            for r in done if r.not_identical or r.lost or r.failed
                            or not r.detected or r.still_damaged]
        + [{"config_change": k, "stale": v[:5]} for k, v in stale.items() if v],
    }


def stale_after_changes(work: Path, raw: dict[str, Any],
                        changes: dict[str, dict[str, Any]]) -> dict[str, list[str]]:
    """Per config change: the files of the clean output rerun with the change that differ
    from a fresh run of the changed config."""
    out: dict[str, list[str]] = {}
    for name, update in changes.items():
        changed, fresh = work / "changed", work / "fresh"
        for folder in (changed, fresh):
            shutil.rmtree(folder, ignore_errors=True)
        shutil.copytree(work / "clean", changed)
        failed = run_all(parse_config(_merged({**raw, "output_dir": str(changed)}, update)))
        failed += run_all(parse_config(_merged({**raw, "output_dir": str(fresh)}, update)))
        out[name] = failed + differing(digests(fresh, False), digests(changed, False))
    return out
