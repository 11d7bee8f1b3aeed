"""Fuzzing the two Zarr inputs m3gd reads: a foreign Hugging Face store and its own cache.

HF chunks: a small synthetic mission in the Hugging Face layout (Zarr v2, blosc) is ingested
clean once; each case cuts or flips bytes of one chunk of one array (points, intensity, valid,
timestamp, pose_pos, pose_orien) and ingests the mission in a fresh child process (c-blosc
reads past a short buffer on a process's first decode, so a crash shows only there). The
contract: the child exits 0 (or refuses in one line); a crash is a signal or a traceback;
no rows gained (kept rows <= clean) and the accounting holds (per group, rows read = kept +
rejected: every lost row is a reject).

Cache chunks: a cache group with the arrays m3gd writes (images, latents, g, packed h) is
written once; each case flips 1 to 200 bits somewhere in one stored chunk (its data or its
CRC32C) of one shard, then reads every view through the ShardReader, tensorstore and
zarr-python and runs `verify_cache`. A read that returns bytes different from the clean ones
without raising is a silent corruption (goal 0); `verify_cache` must name the chunk.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import numpy as np

ARRAYS = ("hesai_points_undistorted/points", "hesai_points_undistorted/intensity",
          "hesai_points_undistorted/valid", "hesai_points_undistorted/timestamp",
          "anymal_state_odometry/pose_pos", "anymal_state_odometry/pose_orien",
          "hdr_front/timestamp")  # fmt: skip
"""The store arrays whose chunks the HF cases damage."""

_CHILD = textwrap.dedent("""
    import json, sys
    from pathlib import Path
    from pipeline.ingest.recording import ingest_recording
    from schemas.config import IngestConfig
    cfg = IngestConfig(cameras=["front"], out_height=56, out_width=84)
    try:
        res = ingest_recording(Path(sys.argv[1]), Path(sys.argv[2]), cfg)
    except ValueError as err:
        print(json.dumps({"refused": str(err)}))
        sys.exit(0)
    import pyarrow.parquet as pq
    acc = pq.read_table(res.index_dir / "accounting.parquet").to_pylist()
    gaps = sum(abs(r["read"] - r["kept"] - r["rejected"]) for r in acc)
    print(json.dumps({"images": sum(res.images.values()), "sweeps": res.sweeps,
                      "odometry": res.odometry, "rejects": res.rejects, "gaps": gaps}))
""")


def hf_base(root: Path, seconds: float = 1.5, seed: int = 0) -> Path:
    """The small Hugging Face mission every HF case damages (written once per `root`)."""
    from pipeline.synth.api import synthesize
    from schemas.config import SynthConfig

    mission = root / "hf_base"
    if (mission / "groundtruth" / "faults.json").exists():
        return mission
    cfg = SynthConfig(seed=seed, seconds=seconds, cameras=["front"], image_width=240,
                      image_height=160, points_per_sweep=1024, depth_maps=False,
                      format="hf-zarr")  # fmt: skip
    synthesize(root, cfg, "corridor", "hf_base")
    return mission


def ingest_child(mission: Path, out: Path) -> tuple[int, dict[str, Any], str]:
    """(exit code, the child's result or refusal, its stderr tail) of one ingest."""
    proc = subprocess.run([sys.executable, "-c", _CHILD, str(mission), str(out)],
                          capture_output=True, text=True, timeout=600, check=False)  # fmt: skip
    try:
        got = json.loads(proc.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        got = {}
    return proc.returncode, got, proc.stderr[-400:]


def damage_chunk(path: Path, rng: np.random.Generator) -> str:
    """Cut the chunk file at a random length or flip 1 to 40 random bits; what was done."""
    data = bytearray(path.read_bytes())
    if rng.random() < 0.5 or len(data) < 2:
        cut = int(rng.integers(0, max(1, len(data))))
        path.write_bytes(bytes(data[:cut]))
        return f"cut to {cut} of {len(data)} bytes"
    n = int(rng.integers(1, 41))
    for i in rng.integers(0, len(data), n):
        data[int(i)] ^= 1 << int(rng.integers(0, 8))
    path.write_bytes(bytes(data))
    return f"{n} bits flipped"


def run_hf_cases(work: Path, cases: int, seconds: float, seed: int = 0) -> dict[str, Any]:
    """HF chunk cases until `cases` or `seconds`: crashes (goal 0), refusals, row counts."""
    t0 = time.perf_counter()
    base = hf_base(work / "hf_root", seed=seed)
    rc, clean, err = ingest_child(base, work / "hf_clean_out")
    if rc != 0 or "sweeps" not in clean:
        raise RuntimeError(f"the clean HF mission does not ingest: rc {rc}: {err}")
    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {"hf_cases": 0, "hf_crashes": 0, "hf_refused_in_one_line": 0,
                           "hf_rows_gained": 0, "hf_accounting_gaps": 0,
                           "hf_failures": []}  # fmt: skip
    while out["hf_cases"] < cases and time.perf_counter() - t0 < seconds:
        case = work / "hf_case"
        shutil.rmtree(case, ignore_errors=True)
        shutil.copytree(base, case / "m")
        array = ARRAYS[int(rng.integers(0, len(ARRAYS)))]
        chunks = sorted(p for p in (case / "m" / "data" / array).iterdir()
                        if not p.name.startswith("."))  # fmt: skip
        chunk = chunks[int(rng.integers(0, len(chunks)))]
        what = f"{array}/{chunk.name}: {damage_chunk(chunk, rng)}"
        rc, got, err = ingest_child(case / "m", case / "out")
        out["hf_cases"] += 1
        refused = str(got.get("refused", ""))
        crashed = rc != 0 or not got or "\n" in refused
        gained = sum(max(0, int(got.get(k, 0)) - int(clean[k]))
                     for k in ("images", "sweeps", "odometry"))  # fmt: skip
        out["hf_crashes"] += crashed
        out["hf_refused_in_one_line"] += bool(refused) and not crashed
        out["hf_rows_gained"] += gained
        gaps = int(got.get("gaps", 0))
        out["hf_accounting_gaps"] += gaps
        if crashed or gained or gaps:
            out["hf_failures"].append({"case": what, "rc": rc, "stderr": err[-200:]})
    shutil.rmtree(work / "hf_case", ignore_errors=True)
    return out


def _cache(root: Path) -> tuple[Path, dict[str, np.ndarray]]:
    """A cache group with images, latents, g and packed h of 12 views (shards of 4); the
    group's folder and the clean arrays (h dense)."""
    from schemas.cache_layout import (
        GridSpec,
        GroupAttrs,
        image_arrays,
        latent_array,
        packet_arrays,
    )
    from schemas.packed_cells import occupied_cells, pack_rows
    from store.cache_store import (
        array_dir,
        ensure_array,
        ensure_group,
        open_root,
        write_packed,
        write_region,
    )

    grid, n, shard, c, cu = GridSpec(14 * 8, 14 * 16), 12, 4, 5, 3
    rng = np.random.default_rng(0)
    occupied = rng.random((n, 1, 8, 16)) < 0.6
    g = (rng.normal(size=(n, 6, 8, 16)) * occupied).astype(np.float32)
    g[:, :1] = occupied
    data = {"images": rng.integers(0, 256, (n, grid.image_h, grid.image_w, 3), np.uint8),
            "latents_l0": rng.normal(size=(n, c, 8, 16)).astype(np.float16), "g": g,
            "h": np.where(occupied, rng.uniform(0.5, 2, (n, cu, 8, 16)), 0).astype(np.float16)}
    group = ensure_group(open_root(root / "cache.zarr"), GroupAttrs("rec", "front", n,
                                                                  grid.image_h, grid.image_w,
                                                                  14, shard))  # fmt: skip
    specs = [image_arrays(grid)[0], latent_array(grid, c, "float16"),
             *packet_arrays(grid, cu, True)]  # fmt: skip
    arrays = {s.name: ensure_array(group, s, n, shard) for s in specs}
    for name in ("images", "latents_l0", "g"):
        write_region(arrays[name], 0, data[name])
    write_packed(arrays["h_cells"], 0, pack_rows(data["h"], occupied_cells(g)))
    return array_dir(arrays["g"]).parent, data


def _reads(group: Path, frames: list[int]) -> dict[str, dict[str, Any]]:
    """Every view through each reader: {reader: {array: values or the exception}}."""
    import zarr

    from store.cache_io import read_clip, read_views
    from store.shard_reader import ShardReader

    out: dict[str, dict[str, Any]] = {"shard_reader": {}, "tensorstore": {}, "zarr_python": {}}
    for name in ("images", "latents_l0", "g", "h"):
        for reader, read in (
                ("shard_reader", lambda n: read_clip(group, [n, "g"] if n == "h" else [n],
                                                     frames, ShardReader())[n]),
                ("tensorstore", lambda n: read_views(group / (
                    "h_cells" if n == "h" else n), frames)),
                ("zarr_python", lambda n: zarr.open_array(str(group / (
                    "h_cells" if n == "h" else n)), mode="r")[frames[0]:frames[-1] + 1])):
            try:
                out[reader][name] = np.asarray(read(name))
            except Exception as err:
                out[reader][name] = err
    return out


def _in_stored_chunks(index: bytes, at: Any) -> bool:
    """Whether any byte offset of `at` lies in a stored chunk (data or CRC) of the shard
    whose index (with its CRC32C) is `index`, rather than in the padding between chunks."""
    from store.raw_shard import MISSING
    from store.shard_layout import index_pairs

    pairs = index_pairs(index, (len(index) - 4) // 16)
    pairs = pairs[pairs[:, 0] != MISSING].astype(np.int64)
    at = np.asarray(at, np.int64)[:, None]
    return bool(((at >= pairs[:, 0]) & (at < pairs[:, 0] + pairs[:, 1])).any())


def run_cache_flips(work: Path, flips: int, seed: int = 0) -> dict[str, Any]:
    """`flips` cases of 1 to 200 flipped bits in one stored chunk (data or CRC) of one shard:
    silent corruptions per reader (goal 0) and chunks `verify_cache` missed (goal 0)."""
    from pipeline.cache.verify import verify_cache
    from store.shard_layout import ArrayMeta

    group, _ = _cache(work / "cache_clean")
    frames = list(range(12))
    clean = _reads(group, frames)
    rng = np.random.default_rng(seed)
    silent = dict.fromkeys(clean, 0)
    missed_by_verify = in_padding = 0
    for _ in range(flips):
        case = work / "cache_case"
        shutil.rmtree(case, ignore_errors=True)
        shutil.copytree(group.parent.parent, case / "cache.zarr")
        cgroup = case / "cache.zarr" / "rec" / "front"
        array = ("images", "latents_l0", "g", "h_cells")[int(rng.integers(0, 4))]
        files = sorted(p for p in (cgroup / array / "c").rglob("*") if p.is_file())
        path = files[int(rng.integers(0, len(files)))]
        meta = ArrayMeta.parse(json.loads((cgroup / array / "zarr.json").read_text()))
        assert meta is not None
        n_index = 16 * (meta.file_views * meta.chunks_per_view) + 4
        data = bytearray(path.read_bytes())
        body = len(data) - n_index  # the stored chunks, not the (separately checked) index
        flipped = rng.integers(0, max(1, body), int(rng.integers(1, 201)))
        for i in flipped:
            data[int(i)] ^= 1 << int(rng.integers(0, 8))
        in_chunks = _in_stored_chunks(bytes(data[body:]), flipped)
        path.write_bytes(bytes(data))
        got = _reads(cgroup, frames)
        for reader, arrays in got.items():
            for name, value in arrays.items():
                ref = clean[reader][name]
                if not isinstance(value, Exception) and not np.array_equal(value, ref):
                    silent[reader] += 1
        if in_chunks:
            missed_by_verify += not verify_cache(case / "cache.zarr").corrupt
        else:  # every flip in the padding between chunks: no value can change
            in_padding += 1
    shutil.rmtree(work / "cache_case", ignore_errors=True)
    return {"cache_flips": flips, "cache_flips_only_in_padding": in_padding,
            "silent_cache_corruptions": sum(silent.values()),
            "silent_cache_corruptions_by_reader": silent,
            "cache_flips_missed_by_verify": missed_by_verify}
