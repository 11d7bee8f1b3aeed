"""The point-time proof on every time-convention variant: `m3gd bench variants --only point_time`.

Each variant of `pipeline.synth.variants` that declares per-point times (the `time` group, the
default and `vlp16`) is written, inspected and proven (`pipeline.inspect.prove.prove`); where
ingest inferred which end of the sweep the header stamps (`header` or `first_point`), the same
views are proven again with the other end declared, as a driver that documents its convention
the wrong way round would. The figures: how often the inferred convention is proven, how often
the one declared the wrong way round is switched, and how often a wrong one is proven (must
be 0); the proof's seconds with and without the time judgement.
"""

from __future__ import annotations

import dataclasses
import shutil
import statistics
import time
from pathlib import Path
from typing import Any

FLIP = {"header": "first_point", "first_point": "header"}
"""The ends of the sweep a header stamp can mean, each with the other."""


def time_variants() -> list[str]:
    """The variants with per-point times: the `time_*` ones, the default and vlp16."""
    from pipeline.synth.variants import VARIANTS

    return [n for n in VARIANTS if n.startswith("time_")] + ["default", "vlp16"]


def _reference_cloud(ins: Any, lidar: str) -> Any:
    """The inspection's cloud report of the reference LiDAR topic `lidar`."""
    return next(c for c in ins.clouds if c.topic == lidar)


def _proof_of(ins: Any, data: Any, lidar: str) -> tuple[Any, float]:
    """The point-time proof of `lidar` under `ins` and the whole proof's seconds."""
    from pipeline.inspect.prove import prove

    t0 = time.perf_counter()
    report, _ = prove(ins, data)
    return report.of(f"point_time {lidar}"), time.perf_counter() - t0


def time_proof_row(work: Path, name: str, synth: dict[str, Any]) -> dict[str, Any]:
    """One variant written under `work`, inspected and proven as inferred (and declared the
    other way round where that is a header end): truth, inferred, statuses, seconds."""
    from pipeline.inspect.prove_source import read_proof_data
    from pipeline.inspect.recording import inspect_recording
    from pipeline.synth.api import synthesize
    from pipeline.synth.variants import VARIANTS
    from schemas.config import SynthConfig

    shutil.rmtree(work / name, ignore_errors=True)
    synthesize(work, SynthConfig.model_validate({**synth, "variant": name}), "corridor", name)
    ins = inspect_recording(work / name)
    lidar = next(d.chosen for d in ins.decisions if d.what == "lidar")
    cloud = _reference_cloud(ins, lidar)
    data = read_proof_data(ins, [lidar])
    _proof_of(ins, data, lidar)  # untimed: both timed runs below find the views' caches warm
    proof, seconds = _proof_of(ins, data, lidar)
    no_time = dataclasses.replace(ins, clouds=tuple(
        dataclasses.replace(c, time_field=None) for c in ins.clouds))
    t0 = time.perf_counter()
    _proof_of(no_time, data, lidar)
    truth = VARIANTS[name].lidar.time_convention
    row = {"variant": name, "truth": truth.reference, "inferred": cloud.convention.reference,
           "status": proof.status if proof else "none", "kept": proof.kept if proof else "",
           "note": proof.note if proof else "", "proof_seconds": round(seconds, 3),
           "without_time_seconds": round(time.perf_counter() - t0, 3)}
    if cloud.convention.reference in FLIP:
        wrong = dataclasses.replace(cloud, convention=dataclasses.replace(
            cloud.convention, reference=FLIP[cloud.convention.reference]))
        declared = dataclasses.replace(ins, clouds=tuple(
            wrong if c is cloud else c for c in ins.clouds))
        flipped, _ = _proof_of(declared, data, lidar)
        row["declared_reversed"] = flipped.status if flipped else "none"
        row["declared_reversed_kept"] = flipped.kept if flipped else ""
    return row


def time_proof_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The figures over `rows` (`time_proof_row`): `point_time_wrong_proven` counts a proof
    that kept a convention other than the truth's (the goal is 0); a kept candidate is named
    `<unit> <reference> (...)` (`prove_time.candidates`)."""
    from pipeline.inspect.prove_time import reference_of

    flipped = [r for r in rows if "declared_reversed" in r]
    wrong = sum(r["status"] in ("proven", "switched") and reference_of(r["kept"]) != r["truth"]
                for r in rows)
    wrong += sum(r["declared_reversed"] in ("proven", "switched")
                 and reference_of(r["declared_reversed_kept"]) != r["truth"] for r in flipped)
    extra = [r["proof_seconds"] - r["without_time_seconds"] for r in rows]
    return {
        "point_time_variants": len(rows),
        "point_time_inferred_right": sum(r["inferred"] == r["truth"] for r in rows),
        "point_time_proven": sum(r["status"] == "proven" for r in rows),
        "point_time_declared_reversed": len(flipped),
        "point_time_reversed_switched": sum(r["declared_reversed"] == "switched"
                                            for r in flipped),
        "point_time_wrong_proven": wrong,
        "point_time_seconds_median": round(statistics.median(extra), 3) if extra else None,
        "point_time_rows": rows,
    }


def run_time_proof(work: Path, synth: dict[str, Any],
                   names: list[str] | None = None) -> dict[str, Any]:
    """`time_proof_row` for every variant in `names` (default `time_variants()`), summarized."""
    return time_proof_summary([time_proof_row(work, n, synth)
                               for n in names or time_variants()])
