"""Smoke test of the synth benchmark (tiny sizes; no timed assertion)."""

from __future__ import annotations

from bench.synth_bench import run


def test_bench_reports_consistent_counts() -> None:
    out = run(
        0.5, "plaza", image_width=96, image_height=64, points_per_sweep=300, cameras=["front"]
    )
    assert out["images"] == round((0.5 + 0.3) * 10) and out["sweeps"] == 5
    assert out["points_per_sweep"] == 288
    assert out["synth_wall_s"] > 0 and out["raycast_floor_wall_s"] > 0
    assert out["over_floor"] > 0
