"""`m3gd bench variants`: every sensor variant through the pipeline against the default synth.

For each variant (`pipeline.synth.variants.VARIANTS`) one small recording of the same scene,
seed and motion is synthesized, run through synth, ingest, select and packets in-process (the
stages `m3gd run` runs first), and measured against its ground truth:

- false rejects: messages the run rejected (every reject reason that drops a message read) over
  the messages read; the synthetic recordings hold no damaged message, so every one is false;
- views kept: accepted views over those of the default recording;
- depth abs-rel of the packets against the ground-truth cell depths (`m3gd accuracy`);
- silent losses: messages read but neither kept nor rejected (the accounting);
- which plausibility checks were switched off or capped on which topic (`checks.parquet`);
- time convention errors: variants whose point-time convention, as ingest decided it (the
  sweeps table's time_* columns), is not the one the generator wrote (a refused variant counts).

The checks judge every message (`ingest.checks.trust_checksums` off): the synthetic bags' LZ4
chunks carry checksums, which would otherwise let ingest skip them.

A variant that ingest refuses (a one-line data error before any work) is listed with its
refusal. Goals (the issue's): false_reject_rate_max <= 0.01, views_kept_over_clean_min >= 0.95,
silent_losses 0, time_convention_errors 0, depth_absrel_max within the default's figures.
`--only` takes variant names, group names (`pipeline.synth.variants.GROUPS`: `time`, ...) or
shell patterns (`time_float64_*`).
"""

from __future__ import annotations

import fnmatch
import shutil
import time
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from schemas.config import M3GDConfig
from schemas.errors import DataError
from schemas.recording_index import MESSAGE_REASONS

STAGES_RUN = ["synth", "ingest", "select", "packets"]
SYNTH = {"seconds": 3.0, "image_width": 192, "image_height": 128, "points_per_sweep": 4096,
         "cameras": ["front"], "scenes": ["corridor"]}  # fmt: skip
"""A small recording: 3 s, one camera, 4096 points a sweep."""


def variant_config(work: Path, name: str, synth: dict[str, Any] | None = None) -> M3GDConfig:
    """The config of one variant's run under `work/<name>/`."""
    return M3GDConfig.model_validate({
        "output_dir": str(work / name / "out"),
        "synth": {**SYNTH, **(synth or {}), "variant": name},
        # the checks judge every message (the synthetic chunks are checksummed, which would
        # let them skip every one): what a recording without chunk checksums gets
        "ingest": {"cameras": ["front"], "out_height": 112, "out_width": 168,
                   "checks": {"trust_checksums": False}},
        "cache": {"shard_views": 8},
        "dag": {"retries": 0, "workers": 1},
    })  # fmt: skip


def _message_counts(idx: Path) -> tuple[int, int, int]:
    """(messages read, rejected, unaccounted) of one recording's index."""
    acc = pq.read_table(idx / "accounting.parquet").to_pylist()
    read = sum(int(r["read"]) for r in acc)
    unaccounted = sum(abs(int(r["read"]) - int(r["kept"]) - int(r["rejected"])) for r in acc)
    reasons = {m.value for m in MESSAGE_REASONS}
    rejects = pq.read_table(idx / "rejects.parquet", columns=["reason"]).column(0).to_pylist()
    return read, sum(r in reasons for r in rejects), unaccounted


def run_variant(work: Path, name: str, synth: dict[str, Any] | None = None) -> dict[str, Any]:
    """One variant through synth, ingest, select, packets and accuracy: its row."""
    from dags.graph import STAGES
    from pipeline.analysis.accuracy import run_accuracy
    from pipeline.run.service import RunRequest, run_stages
    from schemas.missions import recording_names

    t0 = time.perf_counter()
    cfg = variant_config(work, name, synth)
    shutil.rmtree(work / name, ignore_errors=True)
    row: dict[str, Any] = {"variant": name}
    summaries = run_stages(cfg, STAGES, RunRequest(only=tuple(STAGES_RUN))).summaries
    failed = {k: v for s in summaries for k, v in s.failed.items()}
    if failed:
        row["refused"] = "; ".join(f"{k}: {v}" for k, v in sorted(failed.items()))
        return row
    (rec,) = recording_names(cfg)
    idx = cfg.layout.index_of(rec)
    read, rejected, unaccounted = _message_counts(idx)
    status = pq.read_table(idx / "selection.parquet", columns=["status"]).column(0).to_pylist()
    checks = pq.read_table(idx / "checks.parquet").to_pylist()
    acc = run_accuracy(cfg, plots=False).summary
    row.update(_time_convention(idx, name))
    row.update(messages=read, rejected=rejected, false_reject_rate=rejected / max(read, 1),
               silent_losses=unaccounted, views=len(status),
               views_kept=sum(s == "ok" for s in status),
               depth_absrel=acc.get("depth_abs_rel"), cells=acc.get("cells"),
               checks_off=sorted(f"{c['check']}@{c['topic']}:{c['state']}" for c in checks
                                 if c["state"] != "on"),
               seconds=round(time.perf_counter() - t0, 1))  # fmt: skip
    return row


def _time_convention(idx: Path, name: str) -> dict[str, Any]:
    """The convention ingest decided (sweeps table) against the one the generator wrote."""
    from pipeline.synth.variants import VARIANTS

    conv = VARIANTS[name].lidar.time_convention
    cols = ["time_field", "time_unit", "time_reference"]
    sweeps = pq.read_table(idx / "sweeps.parquet", columns=cols).to_pylist()
    decided = {" ".join(r[c] for c in cols) for r in sweeps}
    written = f"{conv.field} {conv.unit} {conv.reference}"
    return {"time_written": written, "time_inferred": "; ".join(sorted(decided)),
            "time_convention_ok": decided == {written}}


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The figures over variant rows (the first row is the default, the clean reference)."""
    ran = [r for r in rows if "refused" not in r]
    clean = next((r for r in ran if r["variant"] == "default"), None)
    ref_views = clean["views_kept"] if clean else None
    for r in ran:
        r["views_kept_over_clean"] = (r["views_kept"] / ref_views) if ref_views else None
    absrel = [r["depth_absrel"] for r in ran if r["depth_absrel"] is not None]
    over = [r["views_kept_over_clean"] for r in ran if r["views_kept_over_clean"] is not None]
    return {
        "variants": len(rows),
        "refused": sorted(r["variant"] for r in rows if "refused" in r),
        "false_reject_rate_max": max((r["false_reject_rate"] for r in ran), default=None),
        "views_kept_over_clean_min": min(over, default=None),
        "depth_absrel_max": max(absrel, default=None),
        "depth_absrel_default": clean["depth_absrel"] if clean else None,
        "silent_losses": sum(r["silent_losses"] for r in ran),
        "time_convention_errors": sum(not r.get("time_convention_ok", False) for r in rows),
        "rows": rows,
    }


def run_variants(work: Path, names: list[str] | None = None,
                 synth: dict[str, Any] | None = None) -> dict[str, Any]:
    """Run the default and every variant in `names` (all by default; `select_variants`); the
    figures."""
    names = ["default", *[n for n in select_variants(names) if n != "default"]]
    t0 = time.perf_counter()
    rows = [run_variant(work, n, synth) for n in names]
    out = summarize(rows)
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


def select_variants(names: list[str] | None) -> list[str]:
    """Variant names from names, group names and shell patterns (None: every variant), in
    registry order; DataError for one that matches nothing."""
    from pipeline.synth.variants import GROUPS, VARIANTS

    if not names:
        return list(VARIANTS)
    chosen: set[str] = set()
    for n in names:
        found = set(GROUPS[n]) if n in GROUPS else set(fnmatch.filter(VARIANTS, n))
        if not found:
            raise DataError(f"unknown sensor variant(s) ['{n}']; known groups: "
                            f"{', '.join(GROUPS)}; names: {', '.join(VARIANTS)}")
        chosen |= found
    return [v for v in VARIANTS if v in chosen]
