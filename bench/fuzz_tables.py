"""The table repair loop of `m3gd bench fuzz`: damage one table or metadata file of a finished
output, verify, rerun, compare with the clean output.

The tiny output of `bench.fuzz_repair` is run once (the clean output). Each round copies it
and damages one file that carries a checksum sidecar (`pipeline.run.checksums`: every index
table, the statistics tables and latent parts, the clip index, each cache group's
`zarr.json`), every kind in turn, by one of `DAMAGES`: a flipped bit at a random offset, a
cut at a random length, or deleting the file. Even rounds run `verify` (which must name the
file) and then the stage graph; odd rounds only run the stage graph (which must find the
damage itself). Counted (goal 0 each):

- `tables_damaged_silently`: damaged files the checksum check did not name;
- `tables_repaired_not_identical`: rounds whose output is not byte-identical to the clean
  one afterwards (as `bench.fuzz_repair.digests`: every file, the manifest's finished items);
- `tables_still_damaged` / `tables_failed_items`: damage found again after the rerun / items
  that failed in it.

`readable_after_flip` counts, per kind, the flips of the rounds that left a file Arrow (or
`json`) still parses: what a parse check alone would have let through; `flip_detection` the
same over many more flips per kind, checked without a rerun.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench.fuzz_repair import differing, digests, make_recording, raw_config, run_all, verify
from schemas.config import parse_config

DAMAGES = ("flip", "cut", "delete")
"""How a round damages its file."""


def file_kind(rel: Path) -> str:
    """The kind of a guarded file from its path in the output: `index/<table>`,
    `stats/<folder>`, `cache group zarr.json`, or the file's name."""
    parts = rel.parts
    if parts[0] == "index":
        return f"index/{parts[-1].removesuffix('.parquet')}"
    if parts[0] == "stats":
        return f"stats/{parts[1]}"
    if parts[0] == "cache.zarr":
        return {2: "cache root zarr.json", 3: "cache recording zarr.json",
                4: "cache group zarr.json", 5: "cache array zarr.json"}.get(len(parts),
                                                                          "cache zarr.json")
    return parts[-1]


def guarded_by_kind(out: Path) -> dict[str, list[Path]]:
    """kind -> the guarded files of that kind (paths relative to `out`), sorted: those with
    a checksum sidecar and every `zarr.json` of the cache (parse-checked where Zarr writes
    it without a sidecar: the arrays' and the recording groups')."""
    from pipeline.run.checksums import cache_metadata, guarded_files

    found: dict[str, list[Path]] = {}
    for path in sorted({*guarded_files(out), *cache_metadata(out)}):
        rel = path.relative_to(out)
        found.setdefault(file_kind(rel), []).append(rel)
    return dict(sorted(found.items()))


def damage_file(path: Path, how: str, rng: np.random.Generator) -> str:
    """Damage `path` in place (`how`: one of DAMAGES); returns where, for the report."""
    if how == "delete":
        path.unlink()
        return "deleted"
    data = bytearray(path.read_bytes())
    if how == "cut":
        keep = int(rng.integers(0, len(data)))
        path.write_bytes(bytes(data[:keep]))
        return f"cut at {keep} of {len(data)}"
    at = int(rng.integers(0, len(data)))
    bit = int(rng.integers(0, 8))
    data[at] ^= 1 << bit
    path.write_bytes(bytes(data))
    return f"bit {bit} of byte {at} of {len(data)}"


def still_parses(path: Path) -> bool:
    """Whether a damaged file still parses (Parquet: its rows; else JSON)."""
    import pyarrow.parquet as pq

    try:
        if path.suffix == ".parquet":
            pq.read_table(path)
        else:
            json.loads(path.read_text())
    except Exception:  # any failure to parse counts as detected by parsing
        return False
    return True


@dataclass
class TableRound:
    """One round: the file damaged, how, and how the loop ended."""

    kind: str
    file: str
    damage: str
    via_verify: bool
    detected: bool
    parses: bool
    still_damaged: bool
    not_identical: list[str]
    failed: list[str]


def table_round(clean: Path, case: Path, raw: dict[str, Any], rel: Path, how: str,
                via_verify: bool, rng: np.random.Generator) -> TableRound:
    """Copy `clean` to `case`, damage `rel`, (verify,) rerun, check, compare with `clean`."""
    from pipeline.run.checksums import verify_files

    shutil.rmtree(case, ignore_errors=True)
    shutil.copytree(clean, case)
    where = damage_file(case / rel, how, rng)
    parses = how == "flip" and still_parses(case / rel)
    if via_verify:
        report, _ = verify(case)
        named = [f.path for f in report.files]
    else:
        named = [f.path for f in verify_files(case)[1]]
    failed = run_all(parse_config({**raw, "output_dir": str(case)}))
    again, _ = verify(case)
    return TableRound(file_kind(rel), f"{rel} ({where})", how, via_verify, case / rel in named,
                      parses, again.damaged, differing(digests(clean), digests(case)), failed)


def table_rounds(kinds: dict[str, list[Path]], n: int, rng: np.random.Generator
                 ) -> Iterator[tuple[Path, str, bool]]:
    """(file, damage, via verify) for `n` rounds: every kind in turn, each damage in turn
    (flips most often), a random file of the kind."""
    names = sorted(kinds)
    plan = ("flip", "cut", "flip", "delete")
    for k in range(n):
        files = kinds[names[k % len(names)]]
        how = plan[(k // len(names)) % len(plan)]
        yield files[int(rng.integers(0, len(files)))], how, k % 2 == 0


def run_table_repair(work: Path, n_rounds: int | None = None, seed: int = 0,
                     sections: dict[str, dict[str, Any]] | None = None,
                     flips: int = 100) -> dict[str, Any]:
    """The table repair figures: `n_rounds` rounds (default: two per kind of guarded file);
    `sections`: config sections set on top of the tiny run's (e.g. a stage switched off);
    `flips`: single-bit flips per kind checked for detection only (`flip_detection`)."""
    mission = make_recording(work / "recordings")
    raw = {**raw_config(work / "clean", mission), **(sections or {})}
    shutil.rmtree(work / "clean", ignore_errors=True)
    failed = run_all(parse_config(raw))
    if failed:
        raise RuntimeError(f"the clean table-repair run failed: {failed[0]}")
    kinds = guarded_by_kind(work / "clean")
    rng = np.random.default_rng(seed)
    done = [table_round(work / "clean", work / "case", raw, rel, how, via, rng)
            for rel, how, via in table_rounds(kinds, n_rounds or 2 * len(kinds), rng)]
    figures = summarize_tables(done)
    if flips:
        figures["flip_detection"] = flip_detection(work / "clean", work / "flips", flips, rng)
    return figures


def flip_detection(out: Path, work: Path, flips: int, rng: np.random.Generator
                   ) -> dict[str, dict[str, int]]:
    """Per kind of guarded file of `out`: of `flips` single-bit flips (each on a fresh copy
    of a random file of the kind, no rerun), how many are named (`detected`: by the checksum
    sidecar, or for cache metadata without one by the metadata check) and how many leave a
    file that still parses (`parses`: what a parse check alone lets through)."""
    from pipeline.run.checksums import metadata_problem
    from schemas.atomic_io import check_file, checksum_path

    found: dict[str, dict[str, int]] = {}
    for kind, files in guarded_by_kind(out).items():
        counts = found.setdefault(kind, {"flips": 0, "detected": 0, "parses": 0})
        for _ in range(flips):
            rel = files[int(rng.integers(0, len(files)))]
            case = work / rel  # at its place: array metadata is judged against its group's
            case.parent.mkdir(parents=True, exist_ok=True)
            if len(rel.parts) == 5 and rel.parts[0] == "cache.zarr":
                shutil.copyfile(out / rel.parent.parent / "zarr.json",
                                case.parent.parent / "zarr.json")
            shutil.copyfile(out / rel, case)
            sidecar = checksum_path(out / rel).exists()
            checksum_path(case).unlink(missing_ok=True)
            if sidecar:
                checksum_path(case).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(checksum_path(out / rel), checksum_path(case))
            damage_file(case, "flip", rng)
            counts["flips"] += 1
            counts["detected"] += (check_file(case) if sidecar
                                   else metadata_problem(case)) is not None
            counts["parses"] += still_parses(case)
    return found


def summarize_tables(done: list[TableRound]) -> dict[str, Any]:
    """The figures of a list of rounds."""
    flips: dict[str, list[TableRound]] = {}
    for r in done:
        if r.damage == "flip":
            flips.setdefault(r.kind, []).append(r)
    return {
        "tables_rounds": len(done),
        "tables_damaged_silently": sum(not r.detected for r in done),
        "tables_repaired_not_identical": sum(bool(r.not_identical) for r in done),
        "tables_still_damaged": sum(r.still_damaged for r in done),
        "tables_failed_items": sum(len(r.failed) for r in done),
        "flips_detected": {k: f"{sum(r.detected for r in v)}/{len(v)}"
                           for k, v in sorted(flips.items())},
        "readable_after_flip": {k: f"{sum(r.parses for r in v)}/{len(v)}"
                                for k, v in sorted(flips.items())},
        "tables_failures": [{"file": r.file, "verify": r.via_verify, "detected": r.detected,
                             "differ": r.not_identical[:5], "failed": r.failed[:2]}
                            for r in done if not r.detected or r.not_identical
                            or r.still_damaged or r.failed],
    }
