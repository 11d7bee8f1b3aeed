"""Packets benchmark: structure of the figures at a tiny size (no timing asserts)."""

from __future__ import annotations

import math

from bench import packets_bench


def test_speed_figures_small() -> None:
    out = packets_bench._speed_figures(repeats=1, n_points=3200, c_u=8)
    for key in (
        "speedup_vs_cell_loop",
        "speedup_vs_torch_index_add",
        "time_over_gather_floor",
        "front_surface_over_mean",
    ):
        assert math.isfinite(out[key]) and out[key] > 0
    assert 0.2 < out["n_in_frustum"] / out["n_points"] < 0.45  # about a third in the frustum
    assert all(math.isfinite(v) for v in out.values())


def test_border_figures_front_surface_keeps_only_the_near_layer() -> None:
    out = packets_bench._border_figures()
    assert out["border_cells"] > 0
    assert 0 < out["border_near_fraction_plain"] < 1
    assert out["border_near_fraction_front"] == 1.0
    assert out["single_layer_h_max_abs_diff"] == 0.0
    assert out["border_depth_mean_shift_m"] > 0  # plain pooling is pulled toward the far layer
