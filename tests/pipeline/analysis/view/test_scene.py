"""Pure parts of the view: which views are shown, colours, packet channels, thinning, spawn."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from pipeline.analysis.view.scene import (
    T_world_lidar,
    depth_colors,
    packet_channels,
    plan_views,
    subsample,
)
from pipeline.analysis.view.spawn import has_display, open_viewer


def test_plan_keeps_range_then_earliest_views_with_camera_order_on_ties() -> None:
    stamps = {"front": np.array([10, 20, 30, 40]), "left": np.array([20, 25, 50])}
    p = plan_views(stamps, 20, 40, None)
    assert {c: f.tolist() for c, f in p.frames.items()} == {"front": [1, 2, 3], "left": [0, 1]}
    assert (p.in_range, p.skipped, p.shown, p.last_kept_ns) == (5, 0, 5, 40)
    p = plan_views(stamps, None, None, 2)  # 10 (front), then 20 (front before left)
    assert {c: f.tolist() for c, f in p.frames.items()} == {"front": [0, 1], "left": []}
    assert (p.in_range, p.skipped, p.last_kept_ns) == (7, 5, 20)
    p = plan_views(stamps, None, None, 0)
    assert (p.shown, p.skipped, p.last_kept_ns) == (0, 7, None)
    with pytest.raises(ValueError, match="max_views must be >= 0"):
        plan_views(stamps, None, None, -1)


@given(st.lists(st.integers(-2**62, 2**62), max_size=40), st.integers(0, 50),
       st.one_of(st.none(), st.integers(-2**62, 2**62)))
def test_plan_shows_exactly_the_earliest_in_range(t: list[int], max_views: int,
                                                  start: int | None) -> None:
    stamps = {"a": np.array(t, np.int64)}
    p = plan_views(stamps, start, None, max_views)
    inside = sorted(x for x in t if start is None or x >= start)
    assert p.in_range == len(inside) and p.shown == min(max_views, len(inside))
    assert sorted(np.array(t, np.int64)[p.frames["a"]].tolist()) == inside[:max_views]


def test_depth_colours_run_near_blue_to_far_red() -> None:
    c = depth_colors(np.array([1.0, 5.0, 10.0]), 1.0, 10.0)
    assert c.dtype == np.uint8 and c.shape == (3, 3)
    assert c[0, 2] > c[0, 0] and c[2, 0] > c[2, 2]  # turbo: blue end, red end
    assert (depth_colors(np.full(4, 3.0)) == depth_colors(np.full(1, 3.0))[0]).all()
    assert depth_colors(np.zeros(0)).shape == (0, 3)


def test_packet_channels_decode_eq9_on_occupied_cells_only() -> None:
    g = np.zeros((6, 2, 3), np.float32)
    g[:, 0, 1] = [1, np.log1p(4.0), 0.25, np.log1p(7), 0.5, -0.03]
    ch = packet_channels(g)
    assert ch["validity"].tolist() == [[0, 255, 0], [0, 0, 0]]
    assert ch["mean_depth_m"][0, 1] == pytest.approx(4.0, rel=1e-6)
    assert ch["dtau_s"][0, 1] == pytest.approx(-0.03) and ch["dtau_s"].sum() == ch["dtau_s"][0, 1]
    assert ch["mean_depth_m"].dtype == np.float32
    with pytest.raises(ValueError, match=r"g must be \(6, H, W\)"):
        packet_channels(np.zeros((5, 2, 3)))


def test_subsample_is_even_and_bounded() -> None:
    assert subsample(5, None).tolist() == [0, 1, 2, 3, 4]
    assert subsample(5, 10).tolist() == [0, 1, 2, 3, 4]
    assert subsample(10, 4).tolist() == [0, 2, 5, 7]
    assert subsample(10, 0).size == 0


def test_world_pose_of_the_sweep_is_the_chain_product() -> None:
    T_wc = np.eye(4)
    T_wc[:3, 3] = [1.0, 2.0, 3.0]
    T_cl = np.eye(4)
    T_cl[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]
    T = T_world_lidar(T_wc, T_cl)
    np.testing.assert_allclose(T @ [1.0, 0.0, 0.0, 1.0], [1.0, 2.0, 4.0, 1.0])


def test_spawn_only_with_a_display(tmp_path: Path) -> None:
    started: list[list[str]] = []

    def popen(cmd: list[str], **kw: Any) -> None:
        started.append(cmd)

    path = tmp_path / "x.rrd"
    msg = open_viewer(path, env={}, popen=popen)
    assert not started and "no display" in msg and f"rerun {path}" in msg
    assert open_viewer(path, env={"DISPLAY": ":0"}, popen=popen).startswith("opened")
    assert started == [[started[0][0], "-m", "rerun", str(path)]]
    assert has_display({}, platform="darwin") and not has_display({}, platform="linux")
