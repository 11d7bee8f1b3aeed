"""Time and storage of a whole release from per-item costs: a pure model, no I/O, no timing.

Work model (per scenario, N workers, one CPU thread each):

- ingest  (one task per recording): images x (ingest per image + image cache write);
- select  (one task per recording): images x select per view;
- encode  (one task per shard of `shard_views` views): images x (image encoder + latent write);
- packets (one task per recording): selected sweeps x (sweep decode + point encoder)
  + images x (packet per view + packet write).

Writes cost uncompressed bytes / the measured single-writer Zarr throughput. A stage's wall
time is the makespan lower bound max(W / N, longest task): per-recording stages cannot use more
than `recordings` workers, and their longest task is `longest_over_mean` times the mean
recording's share. Stages run one after another (encode and packets could overlap; not
credited). The whole run also cannot beat (input + output bytes) / aggregate disk bandwidth.
Both bounds are optimistic: scheduling gaps, stragglers and retries only add time.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from schemas.errors import DataError

STAGES = ("ingest", "select", "encode", "packets")
PER_RECORDING = ("ingest", "select", "packets")
HOUR_S = 3600.0


@dataclass(frozen=True)
class Scenario:
    """Encoder costs of one row group: seconds per image and per selected sweep, and sources."""

    name: str
    image_encoder_s: float
    point_encoder_s: float
    source: str


@dataclass(frozen=True)
class Assumptions:
    """The release and machine figures that are not measured here (see docs/scaling.md).

    images: all cameras together (paper: 599,922 images, 48 recordings, three HDR cameras);
    sweeps: selected sweeps, each encoded once (assumed images / 3: LiDAR and cameras both run
    at ~10 Hz, so each sweep is the nearest of about one frame per camera); io_bytes_s:
    aggregate read + write bandwidth of the shared disk in bytes/s; longest_over_mean: longest
    recording over the mean one (per-recording stages wait for it); packets_per_shard_row:
    model packets planned per shard row (`shard_views` frames of every camera) instead of per
    recording, as the DAG does today (a sweep straddling two rows would be encoded twice; the
    model ignores that ~1/shard_views extra work).
    """

    scenarios: tuple[Scenario, ...]
    recordings: int = 48
    images: int = 599_922
    sweeps: int = 199_974
    shard_views: int = 64
    longest_over_mean: float = 2.0
    io_bytes_s: float = 1e9
    cameras: int = 3
    packets_per_shard_row: bool = False

    def __post_init__(self) -> None:
        """Refuse non-positive counts and rates (ValueError names the field)."""
        for name in ("recordings", "images", "sweeps", "shard_views", "io_bytes_s", "cameras"):
            if not getattr(self, name) > 0:
                raise DataError(f"Assumptions.{name} must be > 0, got {getattr(self, name)}")
        if not self.longest_over_mean >= 1.0:
            raise DataError(f"Assumptions.longest_over_mean must be >= 1, got "
                             f"{self.longest_over_mean}")


def stored_bytes_per_view(costs: Mapping[str, float]) -> float:
    """Bytes on disk per view: rectified image + latent + compressed packets + metadata."""
    packets = costs["packet_raw_bytes_view"] * costs["packet_bytes_ratio"]
    return costs["image_bytes_view"] + costs["latent_bytes_view"] + packets + costs[
        "meta_bytes_view"]


def stage_work_s(costs: Mapping[str, float], sc: Scenario, a: Assumptions) -> dict[str, float]:
    """Total single-worker seconds of each stage for the release."""
    write = costs["cache_write_bytes_s"]
    return {
        "ingest": a.images * (costs["ingest_image_s"] + costs["image_bytes_view"] / write),
        "select": a.images * costs["select_view_s"],
        "encode": a.images * (sc.image_encoder_s + costs["latent_bytes_view"] / write),
        "packets": a.sweeps * (costs["decode_sweep_s"] + sc.point_encoder_s)
        + a.images * (costs["packet_view_s"] + costs["packet_raw_bytes_view"] / write),
    }


def stage_tasks(a: Assumptions) -> dict[str, int]:
    """Independent tasks per stage: recordings, or shards for encode (and shard rows for
    packets when `packets_per_shard_row`)."""
    tasks = dict.fromkeys(PER_RECORDING, a.recordings)
    tasks["encode"] = math.ceil(a.images / a.shard_views)
    if a.packets_per_shard_row:
        tasks["packets"] = math.ceil(a.images / (a.cameras * a.shard_views))
    return tasks


def recording_bound(stage: str, a: Assumptions) -> bool:
    """Whether a stage's tasks are whole recordings (so the longest recording bounds it)."""
    return stage in PER_RECORDING and not (stage == "packets" and a.packets_per_shard_row)


def stage_wall_s(work_s: float, tasks: int, workers: int, longest_over_mean: float) -> float:
    """Makespan lower bound max(work / workers, longest task); the longest task is
    `longest_over_mean` x the mean task (work / tasks), and never more than the whole work."""
    return max(work_s / workers, min(work_s, longest_over_mean * work_s / tasks))


def io_bytes(costs: Mapping[str, float], a: Assumptions) -> float:
    """Bytes read (JPEGs, selected sweeps) plus bytes written (the cache) for the release."""
    read = a.images * costs["jpeg_bytes"] + a.sweeps * costs["sweep_bytes"]
    return read + a.images * stored_bytes_per_view(costs)


def scenario_row(costs: Mapping[str, float], sc: Scenario, workers: int,
                 a: Assumptions) -> dict[str, float | str]:
    """One table row: hours per stage, compute and I/O bounds, total hours, TB stored."""
    work = stage_work_s(costs, sc, a)
    tasks = stage_tasks(a)
    row: dict[str, float | str] = {"scenario": sc.name, "workers": float(workers),
                                   "cpu_hours": sum(work.values()) / HOUR_S}
    compute = 0.0
    for stage in STAGES:
        skew = a.longest_over_mean if recording_bound(stage, a) else 1.0
        wall = stage_wall_s(work[stage], tasks[stage], workers, skew)
        row[f"hours_{stage}"] = wall / HOUR_S
        compute += wall
    io_s = io_bytes(costs, a) / a.io_bytes_s
    row["compute_hours"] = compute / HOUR_S
    row["io_hours"] = io_s / HOUR_S
    row["hours"] = max(compute, io_s) / HOUR_S
    row["bound"] = "io" if io_s > compute else "compute"
    row["storage_tb"] = a.images * stored_bytes_per_view(costs) / 1e12
    return row


def scaling_table(costs: Mapping[str, float], n_workers: Sequence[int],
                  assumptions: Assumptions) -> list[dict[str, float | str]]:
    """Rows (scenario x workers) of release hours and TB; adds speedup and efficiency vs N=1."""
    if not n_workers or any(n < 1 for n in n_workers):
        raise DataError(f"n_workers must be a non-empty list of counts >= 1, got {n_workers}")
    rows = []
    for sc in assumptions.scenarios:
        one = scenario_row(costs, sc, 1, assumptions)["hours"]
        for n in n_workers:
            row = scenario_row(costs, sc, n, assumptions)
            row["speedup"] = float(one) / float(row["hours"])
            row["efficiency"] = float(row["speedup"]) / n
            rows.append(row)
    return rows


# Assumed encoder costs (not measurable here); sources in docs/scaling.md.
UTONIA_CPU_S_PER_POINT = 40.0 / 20_000
"""SPEC section 7: Utonia on CPU (enable_flash=False) ~40 s for 20k points; assumed linear in N."""
DA3_GPU_S_PER_IMAGE = 0.02
"""Guess: DA3-Base fp16 runs 26.5 FPS at 504x504 on an Apple M4 Max GPU (38 ms; model card
huggingface.co/mlboydaisuke/Depth-Anything-3-CoreAI); 224x336 is 0.30x the pixels (~11 ms);
rounded up to 20 ms for batch 1 and host transfers. A datacenter GPU should be faster."""
UTONIA_GPU_S_PER_SWEEP = 0.1
"""Guess: PTv3 reports 44 ms inference on ScanNet (Wu et al., arXiv:2312.10035, Fig. 1);
Utonia is a larger PTv3-family model on a 64k-point sweep, so 0.1 s is assumed."""


def default_scenarios(costs: Mapping[str, float]) -> tuple[Scenario, ...]:
    """Embedded encoders (measured), DA3 measured + Utonia assumed on CPU, both assumed on GPU."""
    n_points = costs["n_points"]
    out = [Scenario("embedded patch+fpfh (measured)", costs["encode_patch_image_s"],
                    costs["encode_fpfh_sweep_s"], "both measured here")]
    if "encode_da3_image_s" in costs:
        out.append(Scenario("DA3+Utonia on CPU", costs["encode_da3_image_s"],
                            UTONIA_CPU_S_PER_POINT * n_points,
                            "DA3 measured here (random init); Utonia assumed, SPEC section 7"))
    out.append(Scenario("DA3+Utonia on GPU", DA3_GPU_S_PER_IMAGE, UTONIA_GPU_S_PER_SWEEP,
                        "both assumed (guesses anchored on published figures)"))
    return tuple(out)
