"""Pooled descriptors: every strategy equals the per-cell loop; dtypes, kinds, extremes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from bench.support.packet_reference import reference_pool_mean
from packets.pooling import SEGMENT_POINTS, pool_mean, pool_support
from packets.support import SupportSets
from schemas.errors import DataError

METHODS = ["sparse_mm", "scipy_csr", "torch_index_add", "numpy_add_at", "numpy_reduceat"]
N_CELLS = 6


@st.composite
def pooling_case(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(feat (N, C) float64, point_idx (M,) distinct rows, cell (M,))."""
    n = draw(st.integers(0, 40))
    c = draw(st.integers(1, 5))
    feat = draw(hnp.arrays(np.float64, (n, c), elements=st.floats(-1e3, 1e3)))
    rows = draw(st.lists(st.integers(0, max(n - 1, 0)), unique=True, max_size=n)) if n else []
    idx = np.array(rows, dtype=np.int64)
    cell = draw(hnp.arrays(np.int64, idx.size, elements=st.integers(0, N_CELLS - 1)))
    return feat, idx, cell


def _bound(feat: np.ndarray, idx: np.ndarray, cell: np.ndarray, dtype: type) -> np.ndarray:
    """Worst-case rounding bound of a float mean per cell: (n + 2) ulp(mean |x|), subnormals too."""
    info = np.finfo(dtype)
    n = np.maximum(np.bincount(cell, minlength=N_CELLS), 1)[:, None]
    abs_mean = reference_pool_mean(np.abs(feat), idx, cell, N_CELLS)
    return (n + 2) * (float(info.eps) * abs_mean + float(info.smallest_subnormal))


@pytest.mark.parametrize("method", METHODS)
@settings(max_examples=40, deadline=None)
@given(case=pooling_case())
def test_float64_agrees_with_reference(method: str, case: tuple[np.ndarray, ...]) -> None:
    feat, idx, cell = case
    out = pool_mean(feat, idx, cell, N_CELLS, method)  # type: ignore[arg-type]
    ref = reference_pool_mean(feat, idx, cell, N_CELLS)
    assert out.dtype == np.float64 and out.shape == ref.shape
    assert np.all(np.abs(out - ref) <= 1e-6 * np.abs(ref) + _bound(feat, idx, cell, np.float64))
    empty = np.bincount(cell, minlength=N_CELLS) == 0
    assert np.all(out[empty] == 0)


@pytest.mark.parametrize("method", METHODS)
@settings(max_examples=25, deadline=None)
@given(case=pooling_case())
def test_float32_within_rounding_bound(method: str, case: tuple[np.ndarray, ...]) -> None:
    feat64, idx, cell = case
    feat = feat64.astype(np.float32)
    out = pool_mean(feat, idx, cell, N_CELLS, method)  # type: ignore[arg-type]
    ref = reference_pool_mean(feat, idx, cell, N_CELLS)
    assert out.dtype == np.float32
    assert np.all(np.abs(out - ref) <= _bound(feat.astype(np.float64), idx, cell, np.float32))


def test_numpy_and_torch_paths_agree() -> None:
    rng = np.random.default_rng(0)
    feat = rng.standard_normal((500, 16)).astype(np.float32)
    idx = rng.choice(500, 200, replace=False).astype(np.int64)
    cell = rng.integers(0, N_CELLS, 200)
    a = pool_mean(feat, idx, cell, N_CELLS)
    b = pool_mean(torch.from_numpy(feat), idx, cell, N_CELLS)
    assert isinstance(a, np.ndarray) and isinstance(b, torch.Tensor)
    np.testing.assert_array_equal(a, b.numpy())


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_half_features_pool_in_float32(dtype: torch.dtype) -> None:
    rng = np.random.default_rng(1)
    feat = torch.from_numpy(rng.standard_normal((300, 8)).astype(np.float32)).to(dtype)
    idx = np.arange(0, 300, 2, dtype=np.int64)
    cell = rng.integers(0, N_CELLS, idx.size)
    for method in ("sparse_mm", "torch_index_add", "scipy_csr"):
        out = pool_mean(feat, idx, cell, N_CELLS, method)  # type: ignore[arg-type]
        assert out.dtype == torch.float32
        ref = reference_pool_mean(feat.float().numpy(), idx, cell, N_CELLS)
        np.testing.assert_allclose(out.numpy(), ref, rtol=1e-5, atol=1e-6)


def test_million_points_in_one_cell() -> None:
    rng = np.random.default_rng(2)
    feat = 1e4 + rng.standard_normal((1_000_000, 2))
    idx = np.arange(feat.shape[0], dtype=np.int64)
    cell = np.full(idx.size, 3, dtype=np.int64)
    out = pool_mean(feat, idx, cell, N_CELLS)
    np.testing.assert_allclose(out[3], feat.mean(axis=0), rtol=1e-6)
    assert not out[np.arange(N_CELLS) != 3].any()
    feat32 = feat.astype(np.float32)
    exact = feat32.astype(np.float64).mean(axis=0)
    rel = np.abs(pool_mean(feat32, idx, cell, N_CELLS)[3] - exact) / exact
    # segmented float32 sums stay below (SEGMENT_POINTS + 2) eps32 ...
    assert np.all(rel <= (SEGMENT_POINTS + 2) * np.finfo(np.float32).eps)
    # ... where one sequential float32 scatter-sum over the same data is ~1% off
    plain = pool_mean(feat32, idx, cell, N_CELLS, "torch_index_add")[3]
    assert np.all(np.abs(plain - exact) / exact > 1e-3)


def test_empty_support_all_zero() -> None:
    feat = np.ones((5, 3), dtype=np.float32)
    for method in METHODS:
        out = pool_mean(feat, np.zeros(0, np.int64), np.zeros(0, np.int64), N_CELLS, method)  # type: ignore[arg-type]
        assert out.shape == (N_CELLS, 3) and not out.any()


def test_pool_support_layout_chw() -> None:
    feat = np.arange(12, dtype=np.float32).reshape(4, 3)
    sup = SupportSets(
        point_idx=np.array([1, 3], dtype=np.int64),
        cell=np.array([4, 4], dtype=np.int64),  # row 1, column 1 of a 2 x 3 grid
        depth=np.array([1.0, 2.0]),
        grid_hw=(2, 3),
    )
    h = pool_support(feat, sup)
    assert h.shape == (3, 2, 3)
    np.testing.assert_array_equal(h[:, 1, 1], (feat[1] + feat[3]) / 2)
    assert np.count_nonzero(h.any(axis=0)) == 1


def test_shared_features_across_views_untouched() -> None:
    feat = np.random.default_rng(3).standard_normal((50, 4)).astype(np.float32)
    before = feat.copy()
    va = pool_mean(feat, np.arange(0, 25, dtype=np.int64), np.zeros(25, np.int64), 2)
    vb = pool_mean(feat, np.arange(25, 50, dtype=np.int64), np.ones(25, np.int64), 2)
    np.testing.assert_array_equal(feat, before)
    np.testing.assert_allclose(va[0], feat[:25].mean(0), rtol=1e-5)
    np.testing.assert_allclose(vb[1], feat[25:].mean(0), rtol=1e-5)


def test_bad_indices_rejected() -> None:
    feat = np.ones((5, 3))
    with pytest.raises(ValueError, match="point_idx"):
        pool_mean(feat, np.array([5]), np.array([0]), N_CELLS)
    with pytest.raises(ValueError, match="unknown pooling method"):
        pool_mean(feat, np.array([1]), np.array([0]), N_CELLS, "magic")  # type: ignore[arg-type]


@pytest.mark.parametrize("seed", range(5))
def test_segmented_rows_agree_with_reference(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    import packets.pooling as pooling

    monkeypatch.setattr(pooling, "SEGMENT_POINTS", 3)
    rng = np.random.default_rng(seed)
    feat = rng.standard_normal((80, 5))
    idx = rng.choice(80, 60, replace=False).astype(np.int64)
    cell = rng.integers(0, N_CELLS, 60)
    row, row_cell, n_rows = pooling.segment_rows(cell, N_CELLS)
    assert row_cell is not None and n_rows > N_CELLS
    assert np.all(np.bincount(row, minlength=n_rows) <= 3)
    np.testing.assert_array_equal(row_cell[row], cell)
    out = pool_mean(feat, idx, cell, N_CELLS)
    np.testing.assert_allclose(
        out, reference_pool_mean(feat, idx, cell, N_CELLS), rtol=1e-12, atol=1e-15
    )


def _previous_half_mean(feat: torch.Tensor, idx: np.ndarray, cell: np.ndarray,
                        n_cells: int) -> torch.Tensor:
    """The float16/bfloat16 path before issue 21: every row gathered and cast to float32,
    then the one sparse product of the float32 path (segments combined in float64)."""
    from packets.pooling import _weights, segment_rows

    rows = feat.index_select(0, torch.from_numpy(idx)).float()
    row, row_cell, n_rows = segment_rows(cell, n_cells)
    A = torch.sparse_coo_tensor(torch.from_numpy(np.stack([row, np.arange(idx.size)])),
                                torch.from_numpy(_weights(cell, n_cells)).float(),
                                size=(n_rows, idx.size), check_invariants=False)
    out = torch.sparse.mm(A, rows)
    if row_cell is None:
        return out
    total = torch.zeros((n_cells, out.shape[1]), dtype=torch.float64)
    total.index_add_(0, torch.from_numpy(row_cell), out.double())
    return total.float()


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
@pytest.mark.parametrize("block", [1, 7, 128, 100_000])
def test_half_blocks_bit_identical_to_previous_path(dtype: torch.dtype, block: int,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """Blocked float16 pooling equals the gather-everything path bit for bit: any block
    size, unsorted rows, empty cells, and cells split into segments (> SEGMENT_POINTS)."""
    import packets.pooling as pooling

    monkeypatch.setattr(pooling, "HALF_BLOCK_POINTS", block)
    rng = np.random.default_rng(block)
    n_cells = 40
    feat = torch.from_numpy(rng.standard_normal((6000, 33)).astype(np.float32) * 50).to(dtype)
    idx = rng.choice(6000, 4000, replace=False).astype(np.int64)
    cell = rng.integers(0, n_cells - 5, idx.size)  # the last 5 cells stay empty
    cell[: SEGMENT_POINTS + 300] = 3  # one cell of two segments
    out = pool_mean(feat, idx, cell, n_cells)
    assert out.dtype == torch.float32
    assert torch.equal(out, _previous_half_mean(feat, idx, cell, n_cells))
    assert not out[-5:].any()
    grad = pool_mean(feat.detach().requires_grad_(), idx, cell, n_cells)  # autograd path
    assert torch.equal(grad.detach(), out)


# --- edges the mutation run asked for ------------------------------------------------------------


@pytest.mark.parametrize("dtype", [torch.float16, torch.float32])
def test_no_cells_and_no_points(dtype: torch.dtype) -> None:
    feat = torch.ones((4, 3), dtype=dtype)
    none = np.zeros(0, np.int64)
    assert pool_mean(feat, none, none, 0).shape == (0, 3)
    out = pool_mean(feat, none, none, 3)
    assert out.shape == (3, 3) and not out.any()


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_half_features_with_one_point_and_empty_trailing_cells(dtype: torch.dtype) -> None:
    """A single point (a block of one row and one point) and empty cells after the last
    occupied one: every occupied cell gets its mean, the empty ones zero."""
    feat = torch.arange(12, dtype=dtype).reshape(4, 3)
    one = pool_mean(feat, np.array([2]), np.array([1]), 4)
    np.testing.assert_array_equal(one.numpy(), [[0, 0, 0], [6, 7, 8], [0, 0, 0], [0, 0, 0]])
    two = pool_mean(feat, np.array([0, 3, 1]), np.array([0, 0, 2]), 5)
    np.testing.assert_array_equal(two.numpy(), [[4.5, 5.5, 6.5], [0, 0, 0], [3, 4, 5],
                                                [0, 0, 0], [0, 0, 0]])


def test_any_integer_index_type_is_accepted() -> None:
    feat = np.arange(12, dtype=np.float32).reshape(4, 3)
    got = pool_mean(feat, np.array([0, 1, 3], np.int32), np.array([0, 0, 1], np.uint8), 2)
    np.testing.assert_array_equal(got, [[1.5, 2.5, 3.5], [9.0, 10.0, 11.0]])


@pytest.mark.parametrize(("feat", "idx", "cell", "message"), [
    (np.ones((5, 3)), [5], [0], r"^point_idx must lie in \[0, 5\), got \[5, 5\]$"),
    (np.ones((5, 3)), [-1, 2], [0, 0], r"^point_idx must lie in \[0, 5\), got \[-1, 2\]$"),
    (np.ones((5, 3)), [1, 2], [0], r"^point_idx \(2,\) and cell \(1,\) must be equal 1-D shapes$"),
    (np.ones((5, 3)), [[1]], [[0]], r"^point_idx \(1, 1\) and cell \(1, 1\) must be equal 1-D"),
    (np.ones(5), [1], [0], r"^features must be \(N, C\), got shape \(5,\)$"),
    (np.ones((5, 3), np.int64), [1], [0], r"^features must be floating point, got torch.int64$"),
])
def test_bad_pooling_inputs_are_refused_by_name(feat: np.ndarray, idx: list, cell: list,
                                                message: str) -> None:
    with pytest.raises(DataError, match=message):
        pool_mean(feat, np.array(idx), np.array(cell), N_CELLS)


def test_pool_support_passes_its_method_on() -> None:
    sup = SupportSets(point_idx=np.array([1]), cell=np.array([0]), depth=np.array([1.0]),
                      grid_hw=(1, 2))
    with pytest.raises(DataError, match="unknown pooling method 'magic'"):
        pool_support(np.ones((3, 2)), sup, "magic")  # type: ignore[arg-type]
