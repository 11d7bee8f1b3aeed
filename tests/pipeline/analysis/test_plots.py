"""Plots (issue 9 part 4): valid PNGs of the expected size, deterministic PCA colouring."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from matplotlib.image import imread

from pipeline.analysis.plot_data import dtau_groups, occupancy_frequency, pca_rgb, series_by
from pipeline.analysis.plots import (
    DPI,
    plot_depth_histogram,
    plot_dtau_histograms,
    plot_occupancy,
    plot_occupancy_from_cells,
    plot_pca_side_by_side,
    plot_speed_accuracy,
    plot_training,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _png_size(path: Path) -> tuple[int, int]:
    """(width, height) from the IHDR chunk, after checking the PNG signature; decodes it too."""
    raw = path.read_bytes()
    assert raw[:8] == PNG_MAGIC and raw[12:16] == b"IHDR"
    width, height = struct.unpack(">II", raw[16:24])
    assert imread(path).shape[:2] == (height, width)
    return width, height


def _views() -> pa.Table:
    rng = np.random.default_rng(0)
    n = 60
    return pa.table({
        "recording": ["r0"] * 30 + ["r1"] * 30,
        "camera": (["front", "left"] * 30),
        "frame": np.arange(n, dtype=np.int64),
        "dtau_s": pa.array([None if i == 3 else float(x) for i, x in
                            enumerate(rng.normal(0, 0.02, n))], pa.float64()),
    })


def _cells() -> pa.Table:
    return pa.table({
        "recording": ["r0"] * 4,
        "camera": ["front"] * 4,
        "frame": np.array([0, 0, 1, 1], dtype=np.int64),
        "row": np.array([0, 1, 0, 2], dtype=np.int16),
        "col": np.array([0, 2, 0, 3], dtype=np.int16),
        "n": np.array([5, 1, 2, 0], dtype=np.int64),
    })


def test_dtau_histograms_one_panel_per_recording_camera(tmp_path: Path) -> None:
    path = plot_dtau_histograms(_views(), tmp_path / "sub" / "dtau.png")
    assert _png_size(path) == (3 * 4 * DPI, 2 * 3 * DPI)  # 4 groups -> 3 columns x 2 rows
    empty = plot_dtau_histograms(_views().slice(0, 0), tmp_path / "empty.png")
    assert _png_size(empty) == (4 * DPI, 3 * DPI)


def test_dtau_groups_split_accepted_from_rejected(tmp_path: Path) -> None:
    views = _views().append_column("reject_reason", pa.array(
        ["dtau_exceeded" if i % 10 == 0 else None for i in range(60)], pa.string()))
    ok, bad = dtau_groups(views, accepted=True), dtau_groups(views, accepted=False)
    both = dtau_groups(views)
    for key, all_ in both.items():
        assert ok[key].size + bad.get(key, np.zeros(0)).size == all_.size
    assert sum(b.size for b in bad.values()) == 6  # frames 0, 10, ..., 50
    assert sum(g.size for g in dtau_groups(_views(), accepted=False).values()) == 0
    path = plot_dtau_histograms(views, tmp_path / "split.png", bound_s=0.1)
    assert _png_size(path) == (3 * 4 * DPI, 2 * 3 * DPI)


def test_dtau_groups_hold_each_views_dtau_once_and_skip_missing() -> None:
    views = _views()
    groups = dtau_groups(views)
    assert list(groups) == [("r0", "front"), ("r0", "left"), ("r1", "front"), ("r1", "left")]
    assert [g.size for g in groups.values()] == [15, 14, 15, 15]  # frame 3 (r0/left) has none
    dtau = views.column("dtau_s").to_pylist()
    cams = views.column("camera").to_pylist()
    expect = [x for i, x in enumerate(dtau[30:]) if cams[30 + i] == "left"]
    np.testing.assert_array_equal(groups[("r1", "left")], expect)


def test_occupancy_frequency_counts_supported_cells_per_view(tmp_path: Path) -> None:
    freq = occupancy_frequency(_cells(), (3, 4))
    want = np.zeros((3, 4))
    want[0, 0], want[1, 2] = 1.0, 0.5  # 2 views; (2, 3) has n = 0
    np.testing.assert_array_equal(freq, want)
    np.testing.assert_array_equal(occupancy_frequency(_cells(), (3, 4), n_views=4), want / 2)
    with pytest.raises(ValueError, match="outside"):
        occupancy_frequency(_cells(), (1, 4))
    assert _png_size(plot_occupancy_from_cells(_cells(), (3, 4), tmp_path / "o.png")) == (600, 450)
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        plot_occupancy(np.zeros(3), tmp_path / "bad.png")


def test_depth_histogram_writes_png_with_and_without_data(tmp_path: Path) -> None:
    d = np.array([0.5, 1.0, 30.0, np.nan, np.inf, 120.0])
    assert _png_size(plot_depth_histogram(d, tmp_path / "d.png")) == (600, 400)
    assert _png_size(plot_depth_histogram([], tmp_path / "e.png")) == (600, 400)


def _features(seed: int, c: int, h: int = 4, w: int = 6) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal((c, h, w))


def test_pca_rgb_is_black_off_support_and_in_unit_range() -> None:
    mask = np.zeros((4, 6), dtype=bool)
    mask[1:, 2:] = True
    feats = _features(1, 16)
    feats[:, ~mask] = 1e6  # unsupported cells must not influence the fit
    rgb = pca_rgb(feats, mask)
    assert rgb.shape == (4, 6, 3)
    assert np.all(rgb[~mask] == 0.0)
    assert rgb[mask].min() >= 0.0 and rgb[mask].max() <= 1.0 and rgb[mask].std() > 0.1
    feats[:, ~mask] = -7.0
    np.testing.assert_array_equal(pca_rgb(feats, mask), rgb)


def test_pca_rgb_is_deterministic_and_sign_canonical() -> None:
    mask = np.ones((4, 6), dtype=bool)
    feats = _features(2, 8)
    rgb = pca_rgb(feats, mask)
    np.testing.assert_array_equal(pca_rgb(feats.copy(), mask), rgb)
    # same axes, negated scores: the percentile map mirrors every channel
    np.testing.assert_allclose(pca_rgb(-feats, mask), 1.0 - rgb, atol=1e-12)
    # reordering the cells (another SVD, possibly other signs) recolours the same cells alike
    flipped = pca_rgb(feats[:, ::-1, ::-1], mask)
    np.testing.assert_allclose(flipped, rgb[::-1, ::-1], atol=1e-12)
    np.testing.assert_allclose(pca_rgb(3.0 * feats + 2.0, mask), rgb, atol=1e-12)


def test_pca_rgb_batched_views_share_one_fit_and_degenerate_cases() -> None:
    feats = np.stack([_features(3, 5), _features(4, 5)])
    masks = np.ones((2, 4, 6), dtype=bool)
    both = pca_rgb(feats, masks)
    assert both.shape == (2, 4, 6, 3)
    assert not np.allclose(both[0], pca_rgb(feats[0], masks[0]))  # joint fit differs
    assert np.all(pca_rgb(feats[0], np.zeros((4, 6), bool)) == 0.0)
    rank1 = np.ones((5, 4, 6)) * np.arange(24.0).reshape(4, 6)
    rgb = pca_rgb(rank1, np.ones((4, 6), bool))
    assert np.all(rgb[..., 1:] == 0.0) and rgb[..., 0].max() == 1.0
    with pytest.raises(ValueError, match="mask"):
        pca_rgb(feats[0], np.ones((3, 6), bool))


def test_pca_side_by_side_png(tmp_path: Path) -> None:
    img = np.random.default_rng(5).integers(0, 256, (56, 84, 3), dtype=np.uint8)
    mask = np.random.default_rng(6).random((4, 6)) > 0.4
    path = plot_pca_side_by_side(img, _features(7, 12), _features(8, 9), mask, tmp_path / "p.png")
    assert _png_size(path) == (1200, 300)
    with pytest.raises(ValueError, match="image"):
        plot_pca_side_by_side(img[..., 0], _features(7, 12), _features(8, 9), mask, path)


def test_speed_accuracy_from_dicts_and_table(tmp_path: Path) -> None:
    rows = [{"K": k, "M": m, "latency_s": 0.1 * k * m, "psnr": 20.0 + k / m}
            for k in (20, 1, 5, 10) for m in (2, 3, 4)]
    rows.append({"K": 5, "M": 2, "latency_s": None, "psnr": None})
    s = series_by(rows, "M", "K", "latency_s")
    assert list(s) == [2, 3, 4]
    np.testing.assert_array_equal(s[3][0], [1, 5, 10, 20])
    np.testing.assert_allclose(s[3][1], [0.3, 1.5, 3.0, 6.0])
    assert _png_size(plot_speed_accuracy(rows, tmp_path / "s.png")) == (1000, 400)
    table = pa.Table.from_pylist(rows)
    path = plot_speed_accuracy(table, tmp_path / "t.png", quality=None)
    assert _png_size(path) == (500, 400)


def _blue_pixels(rgb: np.ndarray) -> int:
    """Pixels of matplotlib's first colour (tab:blue, #1f77b4) in an (H, W, 3) float image."""
    return int((np.abs(rgb - np.array([0x1F, 0x77, 0xB4]) / 255).max(axis=2) < 0.08).sum())


def test_a_training_run_of_one_logged_step_draws_it_and_says_what_is_missing(
        tmp_path: Path) -> None:
    """Was: the training plot of a short run was empty (one point draws no line)."""
    rec = {"kind": "train", "step": 4, "loss": 0.8, "grad_norm": 1.5, "lr": 1e-3,
           "steps_per_s": 0.3}
    img = imread(plot_training([rec], tmp_path / "t.png"))[..., :3]
    h, w = img.shape[:2]
    loss_panel, psnr_panel = img[: h // 2, : w // 2], img[h // 2 :, w // 2 :]
    assert _blue_pixels(loss_panel) > 100  # a dot at the one logged loss (the legend: ~60)
    # no eval line: the PSNR panel says so in words (grey text, not an empty frame)
    grey = (np.abs(psnr_panel - 0.35).max(axis=2) < 0.1).sum()
    empty = imread(plot_training([rec, {**rec, "step": 8}], tmp_path / "u.png"))[..., :3]
    assert grey > 200 and _blue_pixels(empty[: h // 2, : w // 2]) > _blue_pixels(loss_panel)
