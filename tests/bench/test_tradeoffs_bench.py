"""The trade-table bench end to end on a short recording (slow: synthesizes several)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.tradeoffs import MARGINS, run_tradeoffs


@pytest.mark.slow
def test_tradeoffs_table_keys_and_invariants(tmp_path: Path) -> None:
    r = run_tradeoffs(tmp_path, seconds=1.5, scenes=("corridor",), max_views=12, sweep_views=3)
    json.dumps(r, allow_nan=False)  # strict JSON
    assert not list(tmp_path.iterdir())  # the recordings are removed
    assert r["max_abs_dt_s"][-1]["views_kept"] == 1.0
    kept = [row["views_kept"] for row in r["max_abs_dt_s"]]
    assert kept == sorted(kept)  # a wider bound keeps at least the same views
    assert r["g_float16_vs_float32_max_rel_depth"] <= 2.0**-11 * 1.001
    assert r["odometry_chain_off_depth_absrel"] > r["depth_absrel"]
    assert r["absrel_per_100ms_dtau_at_1mps_static"] > r["absrel_per_100ms_dtau_at_1mps"]
    assert len(r["front_surface"]) == len(MARGINS)
    assert all(0 <= f["dropped_share"] < 1 for f in r["front_surface"].values())
    assert r["points_1_4_cells_ratio"] <= r["points_1_2_cells_ratio"] <= 1.0
    off = {row["offset_s"]: row for row in r["clock_offset"]}
    assert off[0.1]["uncorrected"] > off[0.1]["corrected"] == pytest.approx(off[0.0]["corrected"])
    assert r["clock_offset_estimate_max_error_s"] < 0.02  # edge alignment finds the offset
    for key in ("jpeg_reduced_time_ratio", "jpeg_reduced_psnr_db", "latents_float16_rel_l2",
                "points_1_2_time_ratio", "depth_absrel_interior", "depth_absrel_border"):
        assert r[key] > 0
