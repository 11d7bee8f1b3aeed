"""Write side of the storage benchmark: the same pipeline run writing to local disk and to S3.

Both runs use one configuration (`bench.loader_bench.tiny_config`: synthesized
recordings, every stage) on the in-process executor, in the same process, alternating
local and S3 for `rounds` rounds; the S3 run writes to the moto server on 127.0.0.1 that
the read benchmark uses (`pipeline.run.remote`: each item fetches what it reads into
scratch, runs, uploads whole objects). Reported: the whole-run ratio `s3_write_over_local`
(best of rounds over best of rounds), the ratio per stage, and what the S3 run sent the
store (requests by method from the server's log, objects and bytes on the store against
the local output's files and bytes). A loopback server has no latency and no bandwidth
limit: on a real store each request adds a round trip, so the request counts carry over
and the time ratio is a floor.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pyarrow.fs as pafs

from bench.support.local_s3 import LocalS3
from pipeline.run.stage import Stage
from schemas.config import M3GDConfig
from store.object_store import filesystem, parse_url


def _timed_run(cfg: M3GDConfig, stages: Sequence[Stage]) -> tuple[float, dict[str, float]]:
    """Seconds of one whole run of `stages` for `cfg` (in-process), and per stage."""
    from pipeline.run.service import run_stages

    start = time.perf_counter()
    summaries = run_stages(cfg, list(stages)).summaries
    seconds = time.perf_counter() - start
    failed = {s.name: s.failed for s in summaries if s.failed}
    if failed:
        raise RuntimeError(f"the write benchmark's run failed: {failed}")
    return seconds, {s.name: s.seconds for s in summaries}


def _local_size(out: Path) -> tuple[int, int]:
    """(files, bytes) of a local output."""
    files = [p for p in out.rglob("*") if p.is_file()]
    return len(files), sum(p.stat().st_size for p in files)


def _store_size(url: str) -> tuple[int, int]:
    """(objects, bytes) below `url`."""
    found = filesystem().get_file_info(pafs.FileSelector(parse_url(url).key(""),
                                                          recursive=True))
    files = [f for f in found if f.type == pafs.FileType.File]
    return len(files), sum(f.size for f in files)


def run_write_bench(config: Callable[[Path], M3GDConfig], stages: Sequence[Stage],
                    workdir: Path, server: LocalS3, bucket: str, rounds: int = 3
                    ) -> dict[str, Any]:
    """Figures of the module docstring; `config(output_dir)` gives the run's config (the
    server's environment must be set by the caller)."""
    local_t: list[float] = []
    s3_t: list[float] = []
    local_stages: dict[str, list[float]] = {}
    s3_stages: dict[str, list[float]] = {}
    requests: dict[str, int] = {}
    url = ""
    for i in range(rounds):
        t, per = _timed_run(config(workdir / f"write-local-{i}"), stages)
        local_t.append(t)
        for k, v in per.items():
            local_stages.setdefault(k, []).append(v)
        url = f"s3://{bucket}/write-{i}"
        before = server.requests()
        t, per = _timed_run(config(Path(url)), stages)
        s3_t.append(t)
        for k, v in per.items():
            s3_stages.setdefault(k, []).append(v)
        if i == 0:
            requests = dict(server.requests() - before)
    files, size = _local_size(workdir / "write-local-0")
    objects, stored = _store_size(f"s3://{bucket}/write-0")
    return {
        "s3_write_over_local": round(min(s3_t) / min(local_t), 3),
        "write_local_s": round(min(local_t), 2), "write_s3_s": round(min(s3_t), 2),
        "s3_write_over_local_by_stage": {
            k: round(min(s3_stages[k]) / max(min(v), 1e-9), 3) for k, v in local_stages.items()},
        "write_requests": requests,
        "write_local_files": files, "write_local_bytes": size,
        "write_s3_objects": objects, "write_s3_bytes": stored,
    }
