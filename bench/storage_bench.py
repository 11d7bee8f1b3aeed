"""Storage benchmark: clip reads from an output on S3 against the same output on local disk.

Everything runs in one process against a moto S3 server started on 127.0.0.1 for the run
(`bench.support.local_s3`, dev dependency moto[server]); request counts come from that
server's log (what the clients really sent). The output is uploaded once, then the 'train'
split is read clip by clip (`ClipStream`, packet mode `full`):
  local       from the local directory (page cache warm after a first pass: the baseline);
  s3_cold     through the read-through shard cache, mirror empty (epoch 1);
  s3_warm     the next epoch (another shuffle) through the same mirror, everything fitting;
  s3_range    the same stored arrays read with ranged GETs straight from S3 (tensorstore's
              s3 kvstore, shard indexes cached in memory): the alternative to whole shards;
              its ratio is over the same tensorstore reader on the local directory (arrays
              read, not decoded into samples).
Ratios are seconds per clip over the local seconds per clip; times are the best of the
rounds, the local baseline measured before and after the S3 reads of each round. A loopback
server has no network latency: on a real store each GET also costs a round trip (10-100 ms),
which makes `requests_per_clip_read` the figure that carries over. When the output holds
synthesized recordings, staging one mission from S3 (`pipeline.ingest.sources.staging`: list, fetch
every file, remove) is timed against copying the same folder on local disk. When the bench
builds its own output, the write side is measured too: the same pipeline run writing to
local disk and to the same S3 server (`bench.storage_write`, `s3_write_over_local`).
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from bench.support.local_s3 import LocalS3, environment, local_s3
from model.dataset import NEEDS, ClipStream
from pipeline.run.stage import Stage
from schemas.cache_layout import GROUP_TEMPLATE
from schemas.layout import CACHE_DIRNAME
from store.object_store import filesystem, parse_url
from store.shard_cache import ShardCache, stored_names

BUCKET = "m3gd-bench"
WriteBench = Callable[[Path, LocalS3], dict[str, Any]]


def upload_tree(local: Path, url: str) -> int:
    """Copy the directory `local` to `url` (whole objects); return the bytes copied."""
    import pyarrow.fs as pafs

    pafs.copy_files(str(local), parse_url(url).key(""),
                    source_filesystem=pafs.LocalFileSystem(),
                    destination_filesystem=filesystem())
    return sum(p.stat().st_size for p in local.rglob("*") if p.is_file())


def _read_epoch(stream: ClipStream, epoch: int) -> tuple[float, int]:
    """Seconds and clips of one pass over the stream's clips for `epoch`."""
    stream.set_epoch(epoch)
    start, n = time.perf_counter(), 0
    for _ in stream:
        n += 1
    return time.perf_counter() - start, n


def _gets(server: LocalS3) -> int:
    """Object reads served so far: GETs and the HEADs that precede some of them."""
    counts = server.requests()
    return counts["GET"] + counts["HEAD"]


def _range_reader(base: str, server: LocalS3 | None) -> Any:
    """read(group, names, frames): a clip's stored arrays via tensorstore, from the output
    directory `base` (file kvstore) or with ranged GETs from the URL `base` (s3 kvstore)."""
    import tensorstore as ts

    ctx = ts.Context({"cache_pool": {"total_bytes_limit": 64 << 20}})
    handles: dict[str, Any] = {}

    def kvstore(path: str) -> dict[str, Any]:
        if server is None:
            return {"driver": "file", "path": f"{base}/{path}/"}
        url = parse_url(base)
        return {"driver": "s3", "bucket": url.bucket, "path": url.child(path).prefix + "/",
                "endpoint": server.endpoint, "aws_region": "us-east-1",
                "aws_credentials": {"type": "environment"}}

    def handle(path: str) -> Any:
        if path not in handles:
            spec = {"driver": "zarr3", "kvstore": kvstore(path)}
            handles[path] = ts.open(spec, read=True, context=ctx).result()
        return handles[path]

    def read(group: str, names: list[str], frames: list[int]) -> None:
        futures = [handle(f"{CACHE_DIRNAME}/{group}/{n}")[frames].read()
                   for n in stored_names(names)]
        for f in futures:
            f.result()

    return read


def _range_epoch(stream: ClipStream, base: str, server: LocalS3 | None
                 ) -> tuple[float, int]:
    """Seconds and GETs of reading every clip's stored arrays (no decoding into samples)
    with `_range_reader` (GETs counted for S3 only)."""
    read = _range_reader(base, server)
    names = ["latents_l0", "K", "T_world_cam", *NEEDS[stream.mode]]
    clips = stream.clips
    read(GROUP_TEMPLATE.format(recording=clips[0]["recording"], camera=clips[0]["camera"]),
         names, list(clips[0]["frames"]))  # open the handles (metadata) outside the count
    before, start = _gets(server) if server else 0, time.perf_counter()
    for clip in clips:
        group = GROUP_TEMPLATE.format(recording=clip["recording"], camera=clip["camera"])
        read(group, names, list(clip["frames"]))
    return time.perf_counter() - start, (_gets(server) - before if server else 0)


def _round(output_dir: Path, url: str, server: LocalS3, mirror_dir: Path, limit: int
           ) -> dict[str, Any]:
    """One round of the four reads (module docstring): seconds and requests of each."""
    local = ClipStream(output_dir, "train", seed=0)
    _read_epoch(local, 0)  # warm the page cache: the baseline reads memory, like S3's
    t_local, n = _read_epoch(local, 0)
    mirror = ShardCache(parse_url(url), mirror_dir, limit_bytes=limit)
    remote = ClipStream(url, "train", seed=0, remote=mirror)
    before = _gets(server)
    t_cold, _ = _read_epoch(remote, 0)
    gets_cold = _gets(server) - before
    first = dict(mirror.stats)
    before = _gets(server)
    t_warm, _ = _read_epoch(remote, 1)
    gets_warm = _gets(server) - before
    t_range, gets_range = _range_epoch(remote, url, server)
    t_range_local, _ = _range_epoch(local, str(output_dir), None)
    t_local = min(t_local, _read_epoch(local, 0)[0])  # before and after: load drifts
    warm = {k: mirror.stats[k] - first.get(k, 0) for k in ("hits", "misses")}
    return {"n": n, "local": t_local, "cold": t_cold, "warm": t_warm, "range": t_range,
            "range_local": t_range_local, "gets_cold": gets_cold, "gets_warm": gets_warm,
            "gets_range": gets_range,
            "first": first, "warm_stats": warm}


def _staging(output_dir: Path, server: LocalS3, tmp: Path, rounds: int) -> dict[str, Any]:
    """Staging one mission of the output's recordings folder from S3 (fetch, then remove)
    against copying the same folder on local disk (copytree, then remove): best of rounds."""
    import shutil

    from pipeline.ingest.sources.staging import staged
    from schemas.layout import OutputLayout

    missions = sorted(p for p in OutputLayout(output_dir).recordings.glob("*") if p.is_dir())
    if not missions:
        return {}
    mission = missions[0]
    url = f"s3://{BUCKET}/missions/{mission.name}"
    size = upload_tree(mission, url)
    files = sum(1 for p in mission.rglob("*") if p.is_file())
    t_copy, t_stage, requests = [], [], 0
    with environment({"M3GD_SCRATCH": str(tmp)}):
        for _ in range(rounds):
            start = time.perf_counter()
            shutil.copytree(mission, tmp / "copy")
            shutil.rmtree(tmp / "copy")
            t_copy.append(time.perf_counter() - start)
            before, start = _gets(server), time.perf_counter()
            with staged(Path(url)):
                pass
            t_stage.append(time.perf_counter() - start)
            requests = _gets(server) - before
    return {"mission_bytes": size, "mission_files": files,
            "s3_stage_over_local_copy": round(min(t_stage) / min(t_copy), 3),
            "stage_requests_per_file": round(requests / files, 3)}


def _rate(hits: int, misses: int) -> float:
    return round(hits / max(hits + misses, 1), 4)


def run_storage_bench(output_dir: Path, workdir: Path | None = None, rounds: int = 3,
                      write: WriteBench | None = None) -> dict[str, Any]:
    """Figures of the module docstring for the output at `output_dir` (a built cache):
    best of `rounds` alternating rounds (fresh mirror each round) for the times, requests
    and hit rates of the first round; `write(workdir, server)`: the write figures
    (`bench.storage_write`), measured against the same server."""
    with tempfile.TemporaryDirectory(dir=workdir) as tmp, \
            local_s3(Path(tmp) / "moto.log") as server, environment(server.env):
        server.create_bucket(BUCKET)
        url = f"s3://{BUCKET}/out"
        total = upload_tree(output_dir, url)
        runs = [_round(output_dir, url, server, Path(tmp) / f"mirror{i}", total)
                for i in range(rounds)]
        staging = _staging(output_dir, server, Path(tmp), rounds)
        written = write(Path(tmp), server) if write else {"s3_write_over_local": None}
    best = {k: min(r[k] for r in runs)
            for k in ("local", "cold", "warm", "range", "range_local")}
    one, n = runs[0], runs[0]["n"]
    first, warm = one["first"], one["warm_stats"]
    return {
        "clips": n, "output_bytes": total, "bytes_fetched_epoch1": first.get("bytes", 0),
        "local_ms_per_clip": round(1e3 * best["local"] / n, 3),
        "s3_clip_read_over_local": round(best["cold"] / best["local"], 3),
        "s3_warm_clip_read_over_local": round(best["warm"] / best["local"], 3),
        "s3_range_clip_read_over_local": round(best["range"] / best["range_local"], 3),
        "requests_per_clip_read": round(one["gets_cold"] / n, 3),
        "requests_per_clip_read_warm": round(one["gets_warm"] / n, 3),
        "requests_per_clip_read_range": round(one["gets_range"] / n, 3),
        "cache_hit_rate_epoch1": _rate(first.get("hits", 0), first.get("misses", 0)),
        "cache_hit_rate_epoch2": _rate(warm["hits"], warm["misses"]),
        **staging, **written,
    }


def run(stages: Sequence[Stage], output_dir: Path | None = None, rounds: int = 3
        ) -> dict[str, Any]:
    """The storage benchmark on `output_dir`, or on a tiny output built with the real
    pipeline (`stages`, the loader benchmark's configuration) in a temporary directory."""
    if output_dir is not None:  # no configuration to rerun: the write figures need one
        return run_storage_bench(output_dir, rounds=rounds)
    from bench.loader_bench import build_cache, tiny_config
    from bench.storage_write import run_write_bench

    def write(workdir: Path, server: LocalS3) -> dict[str, Any]:
        return run_write_bench(tiny_config, stages, workdir, server, BUCKET, rounds)

    with tempfile.TemporaryDirectory() as tmp:
        built = build_cache(tiny_config(Path(tmp) / "out"), stages)
        return run_storage_bench(built, Path(tmp), rounds, write)
