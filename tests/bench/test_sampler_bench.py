"""Sampler benchmark at tiny sizes: table shape, monotone convergence, adaptive bookkeeping."""

from __future__ import annotations

from pathlib import Path

import torch

from bench.sampler_bench import SamplerBenchSpec, bench_net, run_sampler_bench
from model.train_step import TrainConfig, Trainer
from tests.model.model_fixtures import tiny_cfg

SPEC = SamplerBenchSpec(steps=(1, 4), targets=(2, 3), c=8, c_u=5, grid_hw=(4, 6),
                        image_hw=(56, 84), repeats=1, reference_steps=16, tol=0.5)


def test_table_keyed_by_k_then_m() -> None:
    out = run_sampler_bench(SPEC)
    assert set(out["latency"]) == {"1", "4"} and set(out["latency"]["1"]) == {"2", "3"}
    row = out["latency"]["4"]["3"]
    assert row["latency_s"] > 0 and row["latency_per_target_s"] == row["latency_s"] / 3
    assert row["peak_mem_mb"] >= 0
    q = out["quality_rel_l2_to_reference"]
    assert all(q["4"][m] < q["1"][m] for m in ("2", "3"))  # more steps, closer to converged
    assert 2 <= out["adaptive"]["2"]["steps_taken"] <= 4


def test_loads_checkpoint(tmp_path: Path) -> None:
    Trainer(tiny_cfg(), TrainConfig()).save(tmp_path / "ck")
    out = run_sampler_bench(SPEC, tmp_path / "ck")
    assert out["weights"] == "checkpoint EMA"


def test_raw_weights_are_the_trained_ones_not_the_ema(tmp_path: Path) -> None:
    trainer = Trainer(tiny_cfg(), TrainConfig())
    with torch.no_grad():
        for p in trainer.net.parameters():
            p.add_(0.5)  # as if trained: the raw weights move away from the EMA copy
    trainer.save(tmp_path / "ck")
    spec = SamplerBenchSpec(c=8, c_u=5, grid_hw=(4, 6), image_hw=(56, 84))
    raw, ema = bench_net(spec, tmp_path / "ck", ema=False), bench_net(spec, tmp_path / "ck")
    first = next(iter(trainer.net.state_dict()))
    assert torch.equal(raw.state_dict()[first], trainer.net.state_dict()[first])
    assert torch.equal(ema.state_dict()[first], trainer.ema.state_dict()[first])
    assert not torch.equal(raw.state_dict()[first], ema.state_dict()[first])
    out = run_sampler_bench(SPEC, tmp_path / "ck", ema=False)
    assert out["weights"] == "checkpoint raw"


def test_peak_rss_sees_a_known_allocation() -> None:
    # a fresh process: in a long test process freed memory may still be resident and reused
    import subprocess
    import sys

    code = ("import numpy as np\n"
            "from bench.sampler_bench import PeakRSS\n"
            "with PeakRSS() as mem:\n"
            "    block = np.ones(200 * 2**20, dtype=np.uint8)\n"
            "print(mem.peak / block.nbytes)\n")
    ratio = float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                 check=True).stdout)
    assert 0.8 < ratio < 3
