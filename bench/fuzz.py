"""Fuzzing ingest with damaged bags: every case compared with its clean twin.

A small synthetic recording (front camera, LiDAR, odometry, TF) is written once, its bags
re-chunked into small chunks (as a long real bag has many: LZ4 with the checksum `rosbag record`
writes, or without it, or uncompressed: `compression`), and ingested clean: the twin.
Each case damages one bag (byte flips, truncation, a chunk swap: `fuzz_cases`), ingests the
mission and checks the documented contract:

- no crash: ingest returns, or refuses with a data error (ValueError) in one line;
- accounting: per bag and topic, messages read = kept + rejected (`audit.accounting_gaps`);
- no silent loss: every message of the twin was read or lies in a reported damaged region;
- what reaches the cache equals its clean twin: every image handed to the cache sink, every
  indexed sweep (its counts and its decoded points, as packets will read them) and every pose
  has an identical twin (same stamp, same pixels / points / values), else it is a damaged item
  that got through;
- no NaN/Inf in the index tables;
- the per-message checks refuse no intact message: a message they reject whose raw bytes equal
  the clean twin's is counted (`intact_messages_rejected_by_checks`, goal 0).

`run_fuzz` runs cases until a count or a time budget is spent and adds the lock race, the
Hugging Face store cases and the cache-chunk flips of `bench.fuzz_stores` (`crashes` counts
the bag and HF cases; `silent_cache_corruptions` the flips read back without an error), and
the repair loop of `bench.fuzz_repair` (damage, verify, rerun, verify: `repair_rounds`,
`repair_not_identical`, `arrays_lost_by_repair`, `stale_derived_after_config_change`), and
the table repair loop of `bench.fuzz_tables` (a bit flipped, a cut or a deleted file among
the index tables, statistics, clip index and cache groups' `zarr.json`: `tables_rounds`,
`tables_damaged_silently`, `tables_repaired_not_identical`).
"""

from __future__ import annotations

import hashlib
import shutil
import time
import traceback
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import ConnectionExtRosbag1
from rosbags.rosbag1 import Reader, Writer

from bench.ingest_audit import Key, accounting_gaps, message_times, silent_losses
from bench.support.fuzz_cases import MUTATIONS
from pipeline.ingest.core.stream import CameraImage
from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.bags import BagFile, stamp_ns
from pipeline.ingest.sources.sweep_reader import iter_sweeps
from pipeline.synth.rosio import Compression, set_chunk_compression
from schemas.config import IngestConfig, SynthConfig
from schemas.recording_index import (
    MESSAGE_REASONS,
    ODOMETRY,
    REJECTS,
    SWEEPS,
    read_index_table,
    table_path,
)

CAMERA, LIDAR, ODOM = ("/boxi/hdr/front/image_raw/compressed", "/boxi/hesai/points_undistorted",
                       "/anymal/state_estimator/odometry")  # fmt: skip
TOPICS = (CAMERA, LIDAR, ODOM)
POSE_TOPICS = (ODOM, "/tf")
BAGS = ("hdr_front", "hesai_undist", "anymal_state", "tf_minimal")
INGEST = IngestConfig(cameras=["front"], out_height=112, out_width=168)
CHUNK_BYTES = 24 * 1024
"""Chunk size of the fuzzed bags: several chunks per bag even for a 1.5 s recording."""


def _ros1(ext: object) -> ConnectionExtRosbag1:
    """A ROS 1 bag connection's extension (a ROS 1 reader gives no other)."""
    assert isinstance(ext, ConnectionExtRosbag1), ext
    return ext


def rechunk(path: Path, chunk_bytes: int = CHUNK_BYTES,
            compression: Compression = "roslz4") -> None:  # fmt: skip
    """Rewrite a ROS1 bag with chunks of about `chunk_bytes` (same messages, same order)."""
    tmp = path.with_name(f".{path.name}.rechunk")
    tmp.unlink(missing_ok=True)
    with Reader(path) as src:
        writer = Writer(tmp)
        set_chunk_compression(writer, compression)
        writer.chunk_threshold = chunk_bytes
        with writer:
            conns = {c.id: writer.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data,
                                                 md5sum=c.digest, callerid=_ros1(c.ext).callerid,
                                                 latching=_ros1(c.ext).latching)
                     for c in src.connections}  # fmt: skip
            for conn, stamp, raw in src.messages():
                writer.write(conns[conn.id], stamp, raw)
    tmp.replace(path)


def make_base(root: Path, seconds: float = 1.5, seed: int = 0,
              compression: Compression = "roslz4", variant: str = "default") -> Path:  # fmt: skip
    """The small synthetic mission every case damages (written once per `root`).

    `compression` of its chunks: "roslz4" as `rosbag record` writes LZ4 (with the stream
    checksum), "lz4" as rosbags' writer does (no checksum), "none" (no checksum either).
    `variant`: the sensor variant of the recording (`pipeline.synth.variants`).
    """
    from pipeline.synth.api import synthesize

    mission = root / "base"
    if (mission / "groundtruth" / "faults.json").exists():
        return mission
    cfg = SynthConfig(seed=seed, seconds=seconds, cameras=["front"], image_width=240,
                      image_height=160, points_per_sweep=1024, depth_maps=False,
                      variant=variant)
    synthesize(root, cfg, "corridor", "base")
    for bag in sorted(mission.glob("*.bag")):
        rechunk(bag, compression=compression)
    return mission


@dataclass
class Outputs:
    """What one ingest handed on: image digests by (camera, stamp), sweep and pose rows."""

    images: dict[tuple[str, int], str] = field(default_factory=dict)
    sweeps: dict[int, tuple[Any, ...]] = field(default_factory=dict)
    poses: dict[int, tuple[float, ...]] = field(default_factory=dict)
    nonfinite: int = 0


def ingest_outputs(mission: Path, out: Path) -> tuple[Outputs, Path]:
    """Ingest `mission` into `out`; the images it cached and its index rows (for comparison)."""
    got = Outputs()

    def sink(img: CameraImage) -> None:
        got.images[(img.camera, img.stamp_ns)] = hashlib.sha256(img.image.tobytes()).hexdigest()
        got.nonfinite += int(not np.isfinite(img.K_out).all())

    res = ingest_recording(mission, out, INGEST, sink)
    rows = read_index_table(table_path(res.index_dir, "sweeps"), SWEEPS).to_pylist()
    for r, sweep in zip(rows, iter_sweeps(mission, rows), strict=True):
        points = hashlib.sha256(sweep.xyz.tobytes() + sweep.t_ns.tobytes()).hexdigest()
        got.sweeps[r["stamp_ns"]] = (r["n_points"], r["n_valid"], r["n_nonfinite"], r["n_zero"],
                                     r["t_first_ns"], r["t_last_ns"], points)  # fmt: skip
        got.nonfinite += int(not np.isfinite(sweep.xyz).all())
    for r in read_index_table(table_path(res.index_dir, "odometry"), ODOMETRY).to_pylist():
        values = (*r["position"], *r["quat_xyzw"])
        got.poses[r["stamp_ns"]] = values
        got.nonfinite += int(not np.isfinite(values).all())
    return got, res.index_dir


CHECK_REASONS = frozenset({"corrupt_jpeg", "bad_pointcloud", "bad_pose"})
"""Reasons of the per-message checks: a message they refuse should be a damaged one."""


def message_digests(mission: Path, bags: list[Path]) -> dict[tuple[str, str, int], str]:
    """(bag file, topic, header stamp ns) -> sha256 of the raw bytes, for the streamed topics."""
    out = {}
    for path in bags:
        bag = BagFile(path, mission)
        try:
            for msg in bag.messages(sorted(set(TOPICS) & set(bag.topics()))):
                try:
                    stamp = stamp_ns(bag.deserialize(msg))
                except (ValueError, AttributeError):
                    continue
                out[(msg.file, msg.topic, stamp)] = hashlib.sha256(msg.raw).hexdigest()
        finally:
            bag.close()
    return out


@dataclass
class Twin:
    """The clean run: its outputs, the log times of every message of the streamed topics, and
    the digests of their raw bytes."""

    mission: Path
    outputs: Outputs
    times: dict[Key, list[int]]
    digests: dict[tuple[str, str, int], str] = field(default_factory=dict)

    @classmethod
    def of(cls, mission: Path, work: Path) -> Twin:
        """Ingest the intact mission once."""
        outputs, _ = ingest_outputs(mission, work / "twin_out")
        digests = message_digests(mission, sorted(mission.glob("*.bag")))
        return cls(mission, outputs, message_times(mission, TOPICS), digests)


def good_rejected(twin: Twin, mission: Path, target: Path, rejects: list[dict[str, Any]]) -> int:
    """Messages refused by the per-message checks whose bytes equal the clean twin's."""
    checked = [(r["file"], r["topic"], r["stamp_ns"]) for r in rejects
               if r["reason"] in CHECK_REASONS and r["topic"] in TOPICS]  # fmt: skip
    if not checked:
        return 0
    now = {k: v for k, v in twin.digests.items() if k[0] != target.name}
    now.update(message_digests(mission, [target]))
    return sum(now.get(k) is not None and now.get(k) == twin.digests.get(k) for k in checked)


@dataclass
class CaseResult:
    """One fuzz case: what was done and every way it broke the contract."""

    bag: str
    mutation: str
    seed: int
    what: str
    variant: str = "default"
    refused: str = ""
    crash: str = ""
    accounting_gaps: int = 0
    silent_losses: int = 0
    damaged_images: int = 0
    damaged_sweeps: int = 0
    damaged_poses: int = 0
    nonfinite: int = 0
    rejected_images: int = 0
    rejected_sweeps: int = 0
    good_rejected: int = 0


def _differs(got: dict[Any, Any], clean: dict[Any, Any], atol: float = 0.0) -> int:
    """Items without a twin in `clean` equal to them (within `atol` for numbers)."""
    if not atol:
        return sum(clean.get(k) != v for k, v in got.items())
    return sum(k not in clean or not np.allclose(v, clean[k], rtol=0, atol=atol)
               for k, v in got.items())  # fmt: skip


def run_case(twin: Twin, bag: str, mutation: str, seed: int, work: Path,
             variant: str = "default") -> CaseResult:  # fmt: skip
    """Damage one bag of the twin's mission with `mutation`, ingest, check the contract."""
    case = work / f"{variant}-{bag}-{mutation}-{seed}"
    shutil.rmtree(case, ignore_errors=True)
    mission = case / "base"
    mission.mkdir(parents=True)
    for src in twin.mission.glob("*.bag"):
        (mission / src.name).hardlink_to(src)
    target = mission / f"base_{bag}.bag"
    data, what = MUTATIONS[mutation](target.read_bytes(), np.random.default_rng(seed))
    target.unlink()
    target.write_bytes(data)
    result = CaseResult(bag, mutation, seed, what, variant)
    try:
        got, idx = ingest_outputs(mission, case / "out")
    except ValueError as err:  # a data error: refused in one line (documented, rc 1)
        result.refused = str(err)
        if "\n" in result.refused:
            result.crash = f"multi-line error: {result.refused!r}"
        return result
    except Exception:  # a crash: what this counts
        result.crash = traceback.format_exc()
        return result
    result.accounting_gaps = sum(abs(v) for v in accounting_gaps(idx, POSE_TOPICS).values())
    result.silent_losses = sum(silent_losses(twin.times, idx).values())
    result.damaged_images = _differs(got.images, twin.outputs.images)
    result.damaged_sweeps = _differs(got.sweeps, twin.outputs.sweeps)
    # poses from /tf (when the odometry topic is lost) differ by float rounding only
    result.damaged_poses = _differs(got.poses, twin.outputs.poses, atol=1e-9)
    result.nonfinite = got.nonfinite
    drops = {m.value for m in MESSAGE_REASONS}
    rejects = read_index_table(table_path(idx, "rejects"), REJECTS).to_pylist()
    result.rejected_images = sum(r["topic"] == CAMERA and r["reason"] in drops for r in rejects)
    result.rejected_sweeps = sum(r["topic"] == LIDAR and r["reason"] in drops for r in rejects)
    result.good_rejected = good_rejected(twin, mission, target, rejects)
    shutil.rmtree(case, ignore_errors=True)
    return result


def cases(seed: int) -> Iterator[tuple[str, str, int]]:
    """(bag, mutation, seed) forever: every bag with every mutation, seeds from `seed`."""
    rng = np.random.default_rng(seed)
    while True:
        for mutation in MUTATIONS:
            for bag in BAGS:
                yield bag, mutation, int(rng.integers(0, 2**31))


def summarize(results: list[CaseResult]) -> dict[str, Any]:
    """The fuzz figures (every count's goal is 0) over case results."""
    return {
        "cases_tried": len(results),
        "refused_in_one_line": sum(bool(r.refused) and not r.crash for r in results),
        "refusals": sorted({r.refused.split(": ", 1)[-1][:90] for r in results if r.refused}),
        "crashes": sum(bool(r.crash) for r in results),
        "accounting_gaps": sum(r.accounting_gaps for r in results),
        "silent_losses": sum(r.silent_losses for r in results),
        "damaged_views_cached": sum(r.damaged_images for r in results),
        "damaged_sweeps_indexed": sum(r.damaged_sweeps for r in results),
        "damaged_poses_indexed": sum(r.damaged_poses for r in results),
        "damaged_images_rejected": sum(r.rejected_images for r in results),
        "damaged_sweeps_rejected": sum(r.rejected_sweeps for r in results),
        "nonfinite_values": sum(r.nonfinite for r in results),
        "intact_messages_rejected_by_checks": sum(r.good_rejected for r in results),
    }


def run_fuzz(work: Path, max_cases: int = 40, seconds: float = 120.0, seed: int = 0,
             lock_trials: int = 3, lock_starts: int = 8, compression: Compression = "roslz4",
             variants: list[str] | None = None, hf_cases: int = 12,
             cache_flips: int = 50, repair_rounds: int | None = None,
             table_rounds: int | None = None) -> dict[str, Any]:  # fmt: skip
    """Fuzz cases until `max_cases` or `seconds` are spent, then the lock race; the figures.

    `compression`: how the fuzzed bags' chunks are written (see `make_base`). `variants`:
    sensor variants whose recordings the cases take turns to damage (default: the default).
    `repair_rounds`: rounds of the repair loop (None: one per array kind; 0: none).
    `table_rounds`: rounds of the table repair loop (None: two per kind of table; 0: none).
    """
    t0 = time.perf_counter()
    names = variants or ["default"]
    twins = {v: Twin.of(make_base(work / f"base_root_{v}", seed=seed, compression=compression,
                                  variant=v), work / f"twin_{v}") for v in names}  # fmt: skip
    results: list[CaseResult] = []
    for k, (bag, mutation, case_seed) in enumerate(cases(seed)):
        if len(results) >= max_cases or time.perf_counter() - t0 > seconds:
            break
        v = names[k % len(names)]
        results.append(run_case(twins[v], bag, mutation, case_seed, work / "cases", v))
    figures = summarize(results)
    from bench.fuzz_stores import run_cache_flips, run_hf_cases
    from bench.support.lock_race import race_trials

    if hf_cases:
        hf = run_hf_cases(work / "hf", hf_cases, seconds, seed)
        figures.update({k: v for k, v in hf.items() if k != "hf_failures"})
        figures["crashes"] += hf["hf_crashes"]
    if cache_flips:
        figures.update(run_cache_flips(work / "cache", cache_flips, seed))
    if repair_rounds != 0:  # None: one round per array kind
        from bench.fuzz_repair import run_repair

        repair = run_repair(work / "repair", repair_rounds, seed)
        figures["failures"] = repair.pop("repair_failures")
        figures.update(repair)
    if table_rounds != 0:  # None: two rounds per kind of table
        from bench.fuzz_tables import run_table_repair

        tables = run_table_repair(work / "tables", table_rounds, seed)
        figures["failures"] = figures.get("failures", []) + tables.pop("tables_failures")
        figures.update(tables)
    race = race_trials(work / "lock", trials=lock_trials, n=lock_starts)
    figures.update(lock_starts=race["starts"], lock_double_holds=race["double_holds"],
                   seconds=round(time.perf_counter() - t0, 1), seed=seed,
                   compression=compression, variants=names)
    figures["failures"] = figures.get("failures", []) + [
        {"variant": r.variant, "bag": r.bag, "mutation": r.mutation, "seed": r.seed,
         "what": r.what,
         "crash": r.crash.splitlines()[-1] if r.crash else "",
         "damaged": r.damaged_images + r.damaged_sweeps + r.damaged_poses,
         "silent_losses": r.silent_losses, "accounting_gaps": r.accounting_gaps,
         "intact_rejected": r.good_rejected}
        for r in results
        if r.crash or r.silent_losses or r.accounting_gaps or r.nonfinite or r.good_rejected
        or r.damaged_images or r.damaged_sweeps or r.damaged_poses
    ]  # fmt: skip
    if hf_cases:
        figures["failures"] += hf["hf_failures"]
    return figures
