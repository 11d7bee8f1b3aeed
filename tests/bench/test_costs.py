"""Per-item costs and the release scaling model: exact answers on hand-computed inputs, and a
smoke run of the measurement at tiny sizes (no timing asserts)."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from bench.costs import COST_KEYS, measure_in_worker, measure_item_costs
from bench.costs_stages import view_bytes
from bench.scaling import (
    Assumptions,
    Scenario,
    default_scenarios,
    scaling_table,
    stored_bytes_per_view,
)
from bench.scaling_report import (
    merge_best,
    render,
    run_costs_bench,
    runs_table,
    variant_tables,
    with_wall_times,
)

HOUR = 3600.0

# Hand example. Per image: ingest 1 s + 100 B / 100 B/s = 2 s; select 0.5 s; encode 3 s + 2 s
# (latent write) = 5 s; per view packets 1 s + 1 s (write) = 2 s; per sweep 1 s + 9 s = 10 s.
# 6 images, 2 sweeps, 2 recordings, shards of 4 views -> 2 encode tasks; longest recording
# 1.5x the mean. Work: ingest 12, select 3, encode 30, packets 2*10 + 6*2 = 32 -> 77 s.
HAND_COSTS = {
    "ingest_image_s": 1.0, "image_bytes_view": 100.0, "cache_write_bytes_s": 100.0,
    "select_view_s": 0.5, "latent_bytes_view": 200.0, "decode_sweep_s": 1.0,
    "packet_view_s": 1.0, "packet_raw_bytes_view": 100.0, "packet_bytes_ratio": 0.5,
    "meta_bytes_view": 50.0, "jpeg_bytes": 1000.0, "sweep_bytes": 2000.0,
}
HAND_SCENARIO = Scenario("hand", image_encoder_s=3.0, point_encoder_s=9.0, source="test")


def hand_assumptions(io_bytes_s: float = 1000.0) -> Assumptions:
    return Assumptions((HAND_SCENARIO,), recordings=2, images=6, sweeps=2, shard_views=4,
                       longest_over_mean=1.5, io_bytes_s=io_bytes_s)


def test_stored_bytes_per_view_by_hand() -> None:
    assert stored_bytes_per_view(HAND_COSTS) == 100.0 + 200.0 + 100.0 * 0.5 + 50.0


def test_scaling_table_hand_computed() -> None:
    rows = scaling_table(HAND_COSTS, [1, 2, 4], hand_assumptions())
    assert [r["workers"] for r in rows] == [1.0, 2.0, 4.0]
    one, two, four = rows
    for r in rows:
        assert r["cpu_hours"] == pytest.approx(77 / HOUR, rel=1e-12)
        assert r["io_hours"] == pytest.approx(12.4 / HOUR, rel=1e-12)  # 6000+4000+6*400 B
        assert r["storage_tb"] == pytest.approx(6 * 400 / 1e12, rel=1e-12)
        assert r["bound"] == "compute"
    # N = 1: every stage is its whole work
    assert [one[f"hours_{s}"] * HOUR for s in ("ingest", "select", "encode", "packets")] == \
        pytest.approx([12, 3, 30, 32], rel=1e-12)
    assert one["hours"] == pytest.approx(77 / HOUR, rel=1e-12)
    # N = 2: per-recording stages wait for the longest recording (1.5 x work / 2)
    assert [two[f"hours_{s}"] * HOUR for s in ("ingest", "select", "encode", "packets")] == \
        pytest.approx([9, 2.25, 15, 24], rel=1e-12)
    assert two["hours"] == pytest.approx(50.25 / HOUR, rel=1e-12)
    assert two["speedup"] == pytest.approx(77 / 50.25, rel=1e-12)
    assert two["efficiency"] == pytest.approx(77 / 50.25 / 2, rel=1e-12)
    # N = 4: encode has only 2 shard tasks, so nothing gets faster
    assert four["hours_encode"] * HOUR == pytest.approx(15, rel=1e-12)
    assert four["hours"] == two["hours"]


def test_packets_per_shard_row_lifts_the_recording_bound() -> None:
    # 6 images / (3 cameras x 1 view per shard) = 2 packet tasks of equal size (no skew)
    a = Assumptions((HAND_SCENARIO,), recordings=1, images=6, sweeps=2, shard_views=1,
                    longest_over_mean=1.5, io_bytes_s=1000.0, cameras=3,
                    packets_per_shard_row=True)
    row = scaling_table(HAND_COSTS, [2], a)[0]
    assert row["hours_packets"] * HOUR == pytest.approx(16, rel=1e-12)  # 32 / 2 workers
    assert row["hours_ingest"] * HOUR == pytest.approx(12, rel=1e-12)  # one recording: all of it
    per_rec = scaling_table(HAND_COSTS, [2], dataclasses.replace(a, packets_per_shard_row=False))
    assert per_rec[0]["hours_packets"] * HOUR == pytest.approx(32, rel=1e-12)


def test_scaling_table_io_bound() -> None:
    rows = scaling_table(HAND_COSTS, [1, 8], hand_assumptions(io_bytes_s=100.0))
    for r in rows:
        assert r["bound"] == "io"
        assert r["hours"] == pytest.approx(124 / HOUR, rel=1e-12)
        assert r["speedup"] == pytest.approx(1.0, rel=1e-12)


def test_scaling_table_refuses_bad_inputs() -> None:
    with pytest.raises(ValueError, match="n_workers"):
        scaling_table(HAND_COSTS, [0], hand_assumptions())
    with pytest.raises(ValueError, match="longest_over_mean"):
        Assumptions((HAND_SCENARIO,), longest_over_mean=0.5)
    with pytest.raises(ValueError, match="io_bytes_s"):
        Assumptions((HAND_SCENARIO,), io_bytes_s=0.0)
    with pytest.raises(KeyError, match="select_view_s"):
        scaling_table({k: v for k, v in HAND_COSTS.items() if k != "select_view_s"}, [1],
                      hand_assumptions())


@pytest.mark.parametrize("seed", range(8))
def test_more_workers_never_slower_and_never_beat_perfect_scaling(seed: int) -> None:
    rng = np.random.default_rng(seed)
    costs = {k: float(rng.uniform(0.1, 10.0)) for k in HAND_COSTS}
    sc = Scenario("random", float(rng.uniform(0.1, 10)), float(rng.uniform(0.1, 100)), "test")
    a = Assumptions((sc,), recordings=int(rng.integers(1, 60)), images=int(rng.integers(1, 10**5)),
                    sweeps=int(rng.integers(1, 10**4)), shard_views=int(rng.integers(1, 128)),
                    longest_over_mean=float(rng.uniform(1, 3)),
                    io_bytes_s=float(rng.uniform(1, 1e4)))
    rows = scaling_table(costs, [1, 2, 3, 8, 32, 128], a)
    hours = [float(r["hours"]) for r in rows]
    assert all(b <= h * (1 + 1e-12) for h, b in itertools.pairwise(hours))
    for r in rows:
        n = float(r["workers"])
        assert float(r["hours"]) >= float(r["cpu_hours"]) / n * (1 - 1e-12)
        assert 0 < float(r["efficiency"]) <= 1 + 1e-12


def test_default_scenarios_take_measured_and_assumed_figures() -> None:
    costs = {"n_points": 64_000.0, "encode_patch_image_s": 0.03, "encode_fpfh_sweep_s": 6.0,
             "encode_da3_image_s": 1.5}
    names = [s.name for s in default_scenarios(costs)]
    assert len(names) == 3
    cpu = default_scenarios(costs)[1]
    assert cpu.image_encoder_s == 1.5
    assert cpu.point_encoder_s == pytest.approx(40.0 * 64_000 / 20_000)  # SPEC: 40 s / 20k pts
    del costs["encode_da3_image_s"]
    assert len(default_scenarios(costs)) == 2  # no DA3 measurement, no DA3-on-CPU row


def test_view_bytes_follow_the_cache_layout() -> None:
    b = view_bytes((224, 336), 1536, 1224)
    assert b["latent_bytes_view"] == 1536 * 16 * 24 * 2
    assert b["packet_raw_bytes_view"] == 6 * 16 * 24 * 4 + 1224 * 16 * 24 * 2
    assert b["image_bytes_view"] == 224 * 336 * 3


def test_merge_best_takes_each_keys_least_disturbed_run() -> None:
    runs = [{"a_s": 2.0, "cache_write_bytes_s": 1.0, "jpeg_bytes": 7.0, "only_here_s": 5.0},
            {"a_s": 1.0, "cache_write_bytes_s": 3.0, "jpeg_bytes": 7.0}]
    assert merge_best(runs) == {"a_s": 1.0, "cache_write_bytes_s": 3.0, "jpeg_bytes": 7.0}


def test_runs_table_lists_timed_keys_per_run() -> None:
    text = runs_table([{"a_s": 1.5, "n": 3.0, "load_avg_1min": 2.0},
                       {"a_s": 2.5, "n": 3.0, "load_avg_1min": 4.0}])
    assert "| `a_s` | 1.5 | 2.5 |" in text and "| `load_avg_1min` | 2 | 4 |" in text
    assert "`n`" not in text


def test_with_wall_times_swaps_only_timed_keys() -> None:
    costs = {"a_s": 1.0, "a_wall_s": 2.5, "cache_write_bytes_s": 9.0}
    assert with_wall_times(costs) == {"a_s": 2.5, "a_wall_s": 2.5, "cache_write_bytes_s": 9.0}


def test_measure_item_costs_smoke_tiny() -> None:
    costs = measure_item_costs(n_points=2000, point_channels=8, image_channels=1536,
                               raw_hw=(128, 192), out_hw=(28, 42), repeats=1, select_views=40,
                               cache_views=8)
    assert set(costs) == set(COST_KEYS)
    assert all(math.isfinite(v) and v >= 0 for v in costs.values())
    for key in COST_KEYS:
        if key.endswith("_wall_s") or key in ("jpeg_bytes", "sweep_bytes",
                                               "cache_write_bytes_s", "packet_bytes_ratio"):
            assert costs[key] > 0, key
    assert costs["n_points"] == 2000 // 32 * 32 and costs["sweep_bytes"] == 26 * 1984
    assert costs["jpeg_reduction"] in (1.0, 2.0, 4.0, 8.0)
    assert 0 < costs["occupancy"] <= 1
    assert costs["latent_bytes_view"] == 1536 * 2 * 3 * 2
    assert costs["point_channels"] == 8 and costs["torch_threads"] == 1
    assert costs["blas_threads_env"] >= 0
    rows = scaling_table(costs, [1, 2], Assumptions(default_scenarios(costs)))
    assert len(rows) == 6 and all(math.isfinite(float(r["hours"])) for r in rows)
    text = render(costs, Assumptions(default_scenarios(costs)), [1, 2])
    assert "| DA3+Utonia on CPU | 2 |" in text
    assert "per shard row" in variant_tables(costs, [1, 2])


def test_measure_item_costs_without_da3() -> None:
    costs = measure_item_costs(n_points=640, point_channels=4, image_channels=8,
                               raw_hw=(64, 96), out_hw=(14, 28), repeats=1, da3=False,
                               select_views=10, cache_views=4)
    assert "encode_da3_image_s" not in costs and "encode_da3_image_wall_s" not in costs
    assert set(costs) == set(COST_KEYS) - {"encode_da3_image_s", "encode_da3_image_wall_s"}


def test_measure_in_worker_runs_with_one_blas_thread() -> None:
    costs = measure_in_worker(n_points=640, point_channels=4, image_channels=8,
                              raw_hw=(64, 96), out_hw=(14, 28), repeats=1, da3=False,
                              select_views=10, cache_views=4)
    assert costs["blas_threads_env"] == 1 and costs["torch_threads"] == 1
    assert costs["n_points"] == 640 and costs["image_bytes_view"] == 14 * 28 * 3
    with pytest.raises(RuntimeError, match="cost worker"):
        measure_in_worker(n_points=640, no_such_option=1)


def test_run_costs_bench_tiny() -> None:
    out = run_costs_bench(runs=1, n_workers=[1, 4], n_points=640, point_channels=4,
                          image_channels=8, raw_hw=(64, 96), out_hw=(14, 28), repeats=1,
                          da3=False, select_views=10, cache_views=4)
    assert len(out["runs"]) == 1 and out["costs"]["n_points"] == 640
    assert len(out["rows"]) == 2 * 2  # embedded and GPU scenarios (no DA3 measured) x 2 N
    assert "### Runs" in out["markdown"] and "| DA3+Utonia on GPU | 4 |" in out["markdown"]
    with pytest.raises(ValueError, match="runs"):
        run_costs_bench(runs=0)
