"""Alignment metrics at their documented edges: bounds, degenerate sides, n = 3 and 4, names."""

from __future__ import annotations

import numpy as np
import pytest

from packets.alignment_metrics import (
    _cosine_of,
    _safe_corr,
    affinity_corr_sides,
    alignment_metrics,
    knn_sets,
    metrics_from_sides,
    prepare_side,
    rho_pca_sides,
    svcca_sides,
)
from schemas.errors import DataError


def _gauss(seed: int, n: int, p: int) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal((n, p))


def _drawn(seed: int) -> np.ndarray:
    """Features whose rounding pushes raw cosines and correlations just past +-1 (found by
    search: seed 0 for the Gram cosine and SVCCA, seed 2 for the Pearson correlation)."""
    r = np.random.default_rng(seed)
    n, p = int(r.integers(4, 40)), int(r.integers(1, 30))
    return r.standard_normal((n, p)) * 10 ** r.uniform(-3, 3)


def test_cosine_and_correlation_stay_within_minus_one_and_one() -> None:
    gram = prepare_side("X", _drawn(0)).gram
    assert _cosine_of(gram, gram) == 1.0
    assert _cosine_of(gram, -gram) == -1.0
    a = _drawn(2)[:, 0]
    assert _safe_corr(a, a) == 1.0
    assert _safe_corr(a, -a) == -1.0
    side = prepare_side("X", _drawn(0))
    same = svcca_sides(side, side)  # LAPACK rounding differs by build: within 1e-12, never above 1
    assert 1.0 - 1e-12 <= same <= 1.0


def test_cosine_of_a_zero_matrix_is_zero() -> None:
    zero, ones = np.zeros((3, 3)), np.ones((3, 3))
    assert _cosine_of(zero, ones) == 0.0
    assert _cosine_of(ones, zero) == 0.0
    assert _cosine_of(zero, zero) == 0.0
    unit = np.eye(3)[:1]  # norm exactly 1
    assert _cosine_of(unit, unit) == 1.0


def test_correlation_without_variance_is_zero() -> None:
    ramp = np.arange(6.0)
    assert _safe_corr(np.full(6, 3.0), ramp) == 0.0
    assert _safe_corr(ramp, np.full(6, 3.0)) == 0.0
    # rounding-level spread about a large value counts as no variance (relative 1e-12 rule)
    near = 1e6 + 1e-9 * np.array([0.0, 1.0, -1.0, 2.0, 0.0, -2.0])
    assert _safe_corr(near, ramp) == 0.0
    assert _safe_corr(ramp, near) == 0.0
    spread = 1e6 + 5e-8 * np.tile([1.0, -1.0], 50)  # centred norm 5e-7: under 1e-12 x 1e6 x 10
    assert _safe_corr(spread, np.arange(100.0)) == 0.0
    assert _safe_corr(np.arange(100.0), spread) == 0.0


def test_correlation_is_scale_free_down_to_tiny_values() -> None:
    a, b = np.array([0.0, 1.0, 3.0, 2.0]), np.array([1.0, 0.0, 4.0, 4.0])
    want = np.corrcoef(a, b)[0, 1]
    for scale in (1e-13, 1.0, 1e9):
        assert _safe_corr(scale * a, b) == pytest.approx(want, rel=1e-12)
        assert _safe_corr(a, scale * b) == pytest.approx(want, rel=1e-12)
    unit = np.array([-0.5, 0.5, -0.5, 0.5])  # centred norm exactly 1
    assert _safe_corr(unit, 3 * unit) == 1.0
    assert _safe_corr(3 * unit, unit) == 1.0


def test_affinity_correlation_uses_the_off_diagonal_upper_triangle() -> None:
    x, y = _gauss(1, 9, 4), _gauss(2, 9, 3)
    sx, sy = prepare_side("X", x), prepare_side("Y", y)
    iu = np.triu_indices(9, k=1)
    want = np.corrcoef(sx.affinity[iu], sy.affinity[iu])[0, 1]
    assert affinity_corr_sides(sx, sy) == pytest.approx(want, rel=1e-12)


def test_one_channel_features_are_accepted() -> None:
    x = np.arange(5.0)[:, None]
    got = alignment_metrics(x, x ** 2)
    assert -1.0 <= got.rho_pca <= 1.0 and got.cka > 0.0


def test_float32_features_are_computed_in_float64() -> None:
    x, y = _gauss(3, 20, 5).astype(np.float32), _gauss(4, 20, 3).astype(np.float32)
    assert alignment_metrics(x, y) == alignment_metrics(x.astype(np.float64), y.astype(np.float64))


@pytest.mark.parametrize(("x", "message"), [
    (np.zeros(5), r"^X must be a 2-D \(n, channels\) array, got shape \(5,\)$"),
    (np.zeros((5, 0)), r"^X must be a 2-D \(n, channels\) array, got shape \(5, 0\)$"),
    (np.zeros((2, 3)), r"^X has n=2 cells; the diagnostics need >= 3$"),
    (np.array([[0.0, np.inf]] * 4), r"^X has 4 non-finite value\(s\); first at index \(0, 1\)"),
])
def test_bad_image_features_are_refused_naming_x(x: np.ndarray, message: str) -> None:
    with pytest.raises(DataError, match=message):
        alignment_metrics(x, _gauss(0, 5, 2))


def test_different_cell_counts_are_refused_with_both_counts() -> None:
    with pytest.raises(DataError, match=r"^cell counts differ: X has 5, Y has 6$"):
        metrics_from_sides(prepare_side("X", _gauss(0, 5, 2)), prepare_side("Y", _gauss(1, 6, 2)))


def test_debiased_cka_needs_four_cells() -> None:
    three, four = _gauss(5, 3, 2), _gauss(6, 4, 2)
    assert alignment_metrics(three, three ** 3).cka_debiased is None
    assert isinstance(alignment_metrics(four, four ** 3).cka_debiased, float)
    const3, const4 = np.ones((3, 2)), np.ones((4, 2))
    assert alignment_metrics(const3, three).cka_debiased is None
    assert alignment_metrics(const4, four).cka_debiased == 0.0


def test_a_side_without_structure_gives_zero_directly() -> None:
    """rho_PCA and SVCCA of a constant side (rank 0: no scores, no basis) are 0.0 also when
    called on the sides directly, in either argument."""
    const, other = prepare_side("X", np.ones((6, 3))), prepare_side("Y", _gauss(7, 6, 3))
    for a, b in ((const, other), (other, const), (const, const)):
        assert rho_pca_sides(a, b) == 0.0
        assert svcca_sides(a, b) == 0.0


def test_svcca_of_rank_one_sides() -> None:
    """One direction per side: SVCCA is |cos| of the two centred column spaces."""
    u = _gauss(8, 7, 1)[:, 0]
    x = np.outer(u, [1.0, 2.0, -1.0])
    same = svcca_sides(prepare_side("X", x), prepare_side("Y", np.outer(u, [3.0, 1.0])))
    assert same == pytest.approx(1.0, abs=1e-12)
    v = _gauss(9, 7, 1)[:, 0]
    uc, vc = u - u.mean(), v - v.mean()
    want = abs(uc @ vc) / (np.linalg.norm(uc) * np.linalg.norm(vc))
    got = svcca_sides(prepare_side("X", x), prepare_side("Y", np.outer(v, [1.0, 1.0])))
    assert got == pytest.approx(want, rel=1e-9)


def _hsic_song(k: np.ndarray, l: np.ndarray) -> float:
    """Song et al. (2012) eq. 5, the unbiased HSIC estimator, written out."""
    n = k.shape[0]
    kt, lt = k.copy(), l.copy()
    np.fill_diagonal(kt, 0.0)
    np.fill_diagonal(lt, 0.0)
    one = np.ones(n)
    term = (np.trace(kt @ lt) + (one @ kt @ one) * (one @ lt @ one) / ((n - 1) * (n - 2))
            - 2.0 / (n - 2) * one @ kt @ lt @ one)
    return float(term / (n * (n - 3)))


@pytest.mark.parametrize("n", [4, 5])
def test_debiased_cka_at_the_smallest_cell_counts(n: int) -> None:
    x, y = _gauss(10 + n, n, 3), _gauss(20 + n, n, 2)
    k, l = x @ x.T, y @ y.T
    want = _hsic_song(k, l) / np.sqrt(_hsic_song(k, k) * _hsic_song(l, l))
    assert alignment_metrics(x, y).cka_debiased == pytest.approx(want, rel=1e-9, abs=1e-12)


def test_cosine_affinity_stays_within_minus_one_and_one() -> None:
    x = _drawn(0)
    aff = prepare_side("X", np.vstack([x, -x])).affinity
    assert aff.max() == 1.0 and aff.min() == -1.0


def test_knn_sets_exclude_self_and_break_ties_to_the_lower_index() -> None:
    assert knn_sets(np.ones((5, 5)), 2).tolist() == [
        [False, True, True, False, False],
        [True, False, True, False, False],
        [True, True, False, False, False],
        [True, True, False, False, False],
        [True, True, False, False, False],
    ]
    side = prepare_side("X", _gauss(11, 5, 3))
    assert not side.knn.diagonal().any()
    assert side.knn.sum(axis=1).tolist() == [4] * 5  # k = min(10, n - 1)


def test_unit_norm_features_have_structure() -> None:
    side = prepare_side("X", np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 0.0]]))  # norm exactly 1
    assert not side.constant and side.rank == 1


def test_constant_side_has_rank_zero_even_with_rounding_spread() -> None:
    x = 1.0 + 1e-14 * _gauss(12, 6, 3)
    for arr in (np.ones((6, 3)), x):
        side = prepare_side("X", arr)
        assert side.constant and side.rank == 0
        assert side.scores.shape == (6, 0) and side.basis.shape == (6, 0)


def test_side_scores_are_the_centred_data_on_its_principal_axes() -> None:
    x = _gauss(13, 12, 5) * np.array([4.0, 3.0, 2.0, 1.0, 0.5])
    side = prepare_side("X", x)
    assert side.rank == 5
    xc = x - x.mean(axis=0)
    _, s, vt = np.linalg.svd(xc, full_matrices=False)
    np.testing.assert_allclose(np.linalg.norm(side.scores, axis=0), s[:3], rtol=1e-10)
    np.testing.assert_allclose(np.abs(side.scores), np.abs(xc @ vt[:3].T), rtol=1e-8, atol=1e-10)
