"""Distributed-training benchmark: `m3gd train` under torchrun on the CPU (gloo), the deal of
clips, checkpoint kill windows, and the memory and time of sampling and evaluation.

Figures (all measured in this run; nothing is taken from elsewhere):
  ddp_param_max_abs_diff   max |weight difference| after `steps` updates between
                           `torchrun --nproc-per-node 2 -m cli train --batch-size b` and
                           `m3gd train --batch-size 2b` (goal <= 1e-4)
  speedup_2_ranks          updates/s of the 2-rank run over those of the 1-rank run (same
                           global batch; both from their metrics.jsonl). On a machine with
                           fewer free cores than ranks this is below 1: it reports, not asserts
  clips_seen_once          every training clip read exactly once in an epoch by 2 ranks x 2
                           loader workers (weight-1 reads), none dropped
  ranks_disjoint           no clip read by both ranks
  checkpoint_kill_windows_unsafe  saves cut between two of their file operations (every
                           cut) that did not load as the old or the new checkpoint (goal 0)
  sample_peak_rss_gb       peak RSS of `m3gd sample --clips 4` (a separate process)
  eval_seconds_demo        wall seconds of `m3gd eval` (32 clips) of the demo checkpoint
The last two need a demo output (`m3gd demo`, then `m3gd train`): without one they are
measured on the benchmark's own tiny cache and checkpoint, and `scored_on` says which.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
import yaml
from safetensors.torch import load_file

from bench.loader_bench import build_cache, tiny_config
from model.batching import BatchPlan, TrainBatches, make_train_loader
from model.checkpoint import FILE, has_checkpoint, save_steps
from model.compare import net_config_from_cache
from model.dataset import ClipStream
from model.net import NetConfig
from model.train_log import FILENAME, read_log
from model.train_step import TrainConfig, Trainer
from pipeline.run.stage import Stage


@dataclass(frozen=True)
class DdpBenchSpec:
    """Sizes: updates, per-rank batch b, packet mode, clips sampled and evaluated."""

    steps: int = 20
    batch_size: int = 2
    mode: str = "full"
    sample_clips: int = 4
    eval_clips: int = 32


def m3gd(args: Sequence[str], ranks: int = 1) -> list[str]:
    """The command line of `m3gd args` in this interpreter; under torchrun for ranks > 1."""
    if ranks == 1:
        return [sys.executable, "-m", "cli", *args]
    return [sys.executable, "-m", "torch.distributed.run", "--standalone",
            f"--nproc-per-node={ranks}", "-m", "cli", *args]


def write_config(path: Path, output_dir: Path) -> Path:
    """A config on `output_dir` for CPU training with a metrics line every update."""
    path.write_text(yaml.safe_dump({"output_dir": str(output_dir),
                                    "train": {"device": "cpu", "log_every": 1}}))
    return path


def train_run(cfg: Path, out: Path, spec: DdpBenchSpec, ranks: int, batch: int
              ) -> dict[str, Any]:
    """Train `spec.steps` updates on `ranks` ranks at per-rank `batch`: its weights and rate."""
    subprocess.run(m3gd(["-c", str(cfg), "train", "--mode", spec.mode, "--steps",
                         str(spec.steps), "--batch-size", str(batch), "--out", str(out),
                         "--force"], ranks), check=True, capture_output=True, text=True)
    lines = [r for r in read_log(out / FILENAME) if r["kind"] == "train"]
    tensors = load_file(str(out / FILE))
    weights = {k: v for k, v in tensors.items() if k.startswith(("model.", "ema."))}
    seconds = lines[-1]["seconds"] - lines[0]["seconds"]  # the first update warms up
    return {"weights": weights, "steps_per_s": (len(lines) - 1) / seconds}


def max_abs_diff(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> float:
    """Largest |a - b| over tensors of the same names."""
    if a.keys() != b.keys():
        raise ValueError("checkpoints with different tensors")
    return max(float((a[k] - b[k]).abs().max()) for k in a)


def deal(output_dir: Path, mode: str, batch: int, ranks: int = 2, workers: int = 2
         ) -> dict[str, bool]:
    """Read one epoch as `ranks` ranks x `workers` loader workers: each clip once? disjoint?"""
    stream = ClipStream(output_dir, "train", mode, seed=0)
    plan = BatchPlan(len(stream.clips), batch, ranks)
    per_rank: list[Counter[int]] = []
    for rank in range(ranks):
        seen: Counter[int] = Counter()
        for item in make_train_loader(TrainBatches(stream, plan, rank, 0), workers):
            for b in item["micro"]:
                seen.update(int(c) for c, w in zip(b["clip_id"], b["_weight"], strict=True)
                            if w > 0)
        per_rank.append(seen)
    total = sum(per_rank, Counter())
    ids = sorted(int(c["clip_id"]) for c in stream.clips)
    disjoint = all(not set(a) & set(b) for i, a in enumerate(per_rank)
                   for b in per_rank[i + 1:])
    return {"clips_seen_once": sorted(total) == ids and set(total.values()) == {1},
            "ranks_disjoint": disjoint}


def kill_windows(work: Path, cfg: NetConfig) -> dict[str, int]:
    """Cut a save of a `cfg` network after each of its file operations: how many cuts did
    not load as the old or the new checkpoint."""
    old, new = Trainer(cfg, TrainConfig(seed=0)), Trainer(cfg, TrainConfig(seed=1))
    new.step_count = 1
    ops = save_steps(work / "probe", *new.state())
    unsafe = 0
    for cut in range(len(ops) + 1):
        ck = work / f"cut{cut}"
        old.save(ck)
        for _name, op in save_steps(ck, *new.state())[:cut]:
            op()
        try:
            back = Trainer.load(ck)
            ref = old if back.step_count == 0 else new
            same = all(torch.equal(p, q) for p, q in zip(ref.net.parameters(),
                                                         back.net.parameters(), strict=True))
        except Exception:  # any failure to load is an unsafe window
            same = False
        unsafe += not same
    return {"checkpoint_kill_windows": len(ops) + 1, "checkpoint_kill_windows_unsafe": unsafe}


def timed_child(cmd: list[str]) -> tuple[float, float]:
    """(wall seconds, peak RSS GB) of one child process."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _pid, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode() if proc.stderr else ""
    if proc.returncode:
        raise RuntimeError(f"{' '.join(cmd)} failed: {err.strip().splitlines()[-1:]}")
    return seconds, usage.ru_maxrss / 1e6  # ru_maxrss: kB on Linux


def scoring(cfg: Path, checkpoint: Path, work: Path, spec: DdpBenchSpec) -> dict[str, float]:
    """Peak RSS of sampling `sample_clips` clips and wall time of evaluating `eval_clips`."""
    _, rss = timed_child(m3gd(["-c", str(cfg), "sample", str(checkpoint), "--clips",
                               str(spec.sample_clips), "--out", str(work / "samples")]))
    secs, _ = timed_child(m3gd(["-c", str(cfg), "eval", str(checkpoint), "--clips",
                                str(spec.eval_clips), "--result", str(work / "eval.json")]))
    return {"sample_peak_rss_gb": rss, "eval_seconds_demo": secs}


def run_ddp_bench(spec: DdpBenchSpec, stages: Sequence[Stage], work: Path,
                  cache: Path | None = None, demo: Path | None = None) -> dict[str, Any]:
    """Every figure of the module doc; `demo`: an output dir holding train/full."""
    work.mkdir(parents=True, exist_ok=True)
    output_dir = cache or build_cache(tiny_config(work / "cache"), stages)
    cfg = write_config(work / "m3gd.yaml", output_dir)
    one = train_run(cfg, work / "one", spec, 1, 2 * spec.batch_size)
    two = train_run(cfg, work / "two", spec, 2, spec.batch_size)
    result: dict[str, Any] = {
        "ddp_param_max_abs_diff": max_abs_diff(one["weights"], two["weights"]),
        "speedup_2_ranks": two["steps_per_s"] / one["steps_per_s"],
        "steps_per_s_1_rank": one["steps_per_s"], "steps_per_s_2_ranks": two["steps_per_s"],
        **deal(output_dir, spec.mode, spec.batch_size),
        **kill_windows(work, net_config_from_cache(
            ClipStream(output_dir, "train", spec.mode, seed=0), spec.mode, "tiny"))}
    if demo is not None and has_checkpoint(demo / "train" / "full"):
        scored = scoring(write_config(work / "demo.yaml", demo), demo / "train" / "full", work,
                         spec)
        result["scored_on"] = str(demo / "train" / "full")
    else:
        scored = scoring(cfg, work / "one", work, spec)
        result["scored_on"] = str(work / "one")
    result.update(scored)
    result["cpu_count"] = len(os.sched_getaffinity(0))
    result["spec"] = asdict(spec)
    return result
