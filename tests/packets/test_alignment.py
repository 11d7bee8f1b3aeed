"""Alignment diagnostics (issue 9 part 3): known answers, invariances, the null regime."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from packets.alignment import METRICS, alignment_metrics, alignment_report
from packets.alignment_metrics import metrics_from_sides, permute_side, prepare_side
from schemas.errors import DataError
from tests.packets.test_alignment_metrics import _hsic_song
from tests.strategies import feature_pairs, orthogonal_matrices


def _gauss(seed: int, n: int, p: int) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal((n, p))


def _planted(seed: int, n: int = 80, p: int = 40, q: int = 30, snr: float = 3.0):
    """X, Y sharing a rank-3 latent signal Z plus independent noise."""
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((n, 3))
    x = snr * z @ rng.standard_normal((3, p)) + rng.standard_normal((n, p))
    y = snr * z @ rng.standard_normal((3, q)) + rng.standard_normal((n, q))
    return x, y


def test_identical_features_give_one_for_every_metric() -> None:
    x = _gauss(0, 50, 17)
    got = alignment_metrics(x, x).as_dict()
    assert set(got) == set(METRICS)
    for name, value in got.items():
        assert value == pytest.approx(1.0, abs=1e-10), name


def test_reflected_and_rotated_copy_gives_one() -> None:
    x = _gauss(1, 30, 6)
    q, _ = np.linalg.qr(_gauss(2, 6, 6))
    for name, value in alignment_metrics(x, -3.0 * x @ q).as_dict().items():
        assert value == pytest.approx(1.0, abs=1e-10), name


@settings(max_examples=25, deadline=None)
@given(pair=feature_pairs(), seed=st.integers(0, 2**16), scale=st.floats(1e-3, 1e3))
def test_invariant_to_orthogonal_transform_and_isotropic_scaling(pair, seed, scale) -> None:
    x, y = pair
    rng = np.random.default_rng(seed)
    ox, _ = np.linalg.qr(rng.standard_normal((x.shape[1], x.shape[1])))
    oy, _ = np.linalg.qr(rng.standard_normal((y.shape[1], y.shape[1])))
    base = alignment_metrics(x, y).as_dict()
    moved = alignment_metrics(scale * x @ ox, y @ oy / scale).as_dict()
    for name in METRICS:
        assert moved[name] == pytest.approx(base[name], abs=1e-8), name


@settings(max_examples=10, deadline=None)
@given(pair=feature_pairs(max_cells=20, max_channels=8), data=st.data())
def test_invariant_to_drawn_orthogonal_matrix(pair, data) -> None:
    x, y = pair
    o = data.draw(orthogonal_matrices(x.shape[1]))
    base, moved = alignment_metrics(x, y), alignment_metrics(x @ o, y)
    assert moved.as_dict() == pytest.approx(base.as_dict(), abs=1e-8)


@settings(max_examples=25, deadline=None)
@given(pair=feature_pairs())
def test_values_are_bounded_and_finite(pair) -> None:
    x, y = pair
    for name, value in alignment_metrics(x, y).as_dict().items():
        assert value is not None and np.isfinite(value), name
        assert -1.0 - 1e-12 <= value <= 1.0 + 1e-12, name


def test_biased_cka_matches_feature_space_formula() -> None:
    x, y = _gauss(3, 25, 4), _gauss(4, 25, 5)
    xc, yc = x - x.mean(0), y - y.mean(0)
    want = np.linalg.norm(yc.T @ xc) ** 2 / (np.linalg.norm(xc.T @ xc) * np.linalg.norm(yc.T @ yc))
    assert alignment_metrics(x, y).cka == pytest.approx(want, rel=1e-12)


def test_debiased_cka_matches_song_unbiased_hsic() -> None:
    x, y = _planted(5, n=20, p=7, q=9, snr=0.7)
    k, l = x @ x.T, y @ y.T
    norm = np.sqrt(_hsic_song(k, k) * _hsic_song(l, l))
    want = _hsic_song(k, l) / norm  # uncentred Gram: the estimator ignores the mean
    assert alignment_metrics(x, y).cka_debiased == pytest.approx(want, rel=1e-9)


def test_svcca_known_answer_one_shared_and_one_independent_direction() -> None:
    rng = np.random.default_rng(6)
    x = rng.standard_normal((800, 2))
    y = np.column_stack([x[:, 0] * 2.0 + 1.0, rng.standard_normal(800)])
    assert alignment_metrics(x, y).svcca == pytest.approx(0.5, abs=0.04)  # chance corr ~0.03


def test_jaccard_is_one_when_k_covers_every_other_cell() -> None:
    x, y = _gauss(7, 6, 3), _gauss(8, 6, 4)  # k = min(10, n - 1) = 5: all other cells
    assert alignment_metrics(x, y).jaccard == pytest.approx(1.0)


def test_shuffled_rows_destroy_structure_in_low_dimension() -> None:
    x = _gauss(9, 200, 5)
    y = x[np.random.default_rng(10).permutation(200)]
    got = alignment_metrics(x, y)
    assert abs(got.cka_debiased or 0.0) < 0.1 and abs(got.rho_aff) < 0.1 and got.jaccard < 0.15


def test_independent_high_dimensional_gaussians_biased_cka_high_debiased_near_zero() -> None:
    x, y = _gauss(11, 300, 1536), _gauss(12, 300, 1536)
    report = alignment_report([(x, y)], n_perm=5, seed=0)
    cka, dcka = report.metric("cka"), report.metric("cka_debiased")
    assert 0.75 < cka.value < 0.9  # ~(n-1)/(n-1+n^2/p) = 0.84: dimensionality, not structure
    assert abs(dcka.value) < 0.05
    assert abs(cka.null_mean - cka.value) < 0.02  # the null sees the same inflation
    for name in ("rho_aff", "jaccard", "svcca", "rho_pca"):
        m = report.metric(name)
        assert abs(m.value - m.null_mean) < 0.1, name


def test_planted_low_rank_signal_beats_the_permutation_null() -> None:
    pairs = [_planted(20 + i) for i in range(4)]
    report = alignment_report(pairs, n_perm=19, seed=3)
    for m in report.metrics:
        assert m.n_images == 4, m.name
        assert m.value > m.null_mean + 5 * m.null_std, m.name  # SVCCA-20 is diluted: 3 of 20
        assert m.p_value == pytest.approx(1 / 20), m.name


def test_report_excludes_small_and_constant_images_with_counts() -> None:
    x, y = _planted(30, n=40)
    pairs = [(x, y), (x[:2], y[:2]), (np.ones((10, 4)), _gauss(31, 10, 3)), (x[:3], y[:3])]
    report = alignment_report(pairs, n_perm=3, seed=0)
    assert (report.n_images_seen, report.n_excluded_small, report.n_excluded_constant) == (4, 1, 1)
    assert report.metric("cka").n_images == 2
    assert report.metric("cka_debiased").n_images == 1  # n = 3 has no unbiased HSIC
    rows = report.rows()
    assert [r["metric"] for r in rows] == list(METRICS)
    assert rows[1]["images"] == 2 and rows[1]["excluded_images"] == 2
    assert rows[1]["null_value"] == report.metric("cka").null_mean


def test_report_is_seeded_and_macro_averaged() -> None:
    pairs = [_planted(40 + i, n=30) for i in range(3)]
    a = alignment_report(pairs, n_perm=4, seed=7)
    assert a == alignment_report(iter(pairs), n_perm=4, seed=7)
    assert a.metric("cka").null_mean != alignment_report(pairs, n_perm=4, seed=8).metric(
        "cka").null_mean
    per_image = [alignment_metrics(x, y).rho_aff for x, y in pairs]
    assert a.metric("rho_aff").value == pytest.approx(np.mean(per_image), rel=1e-12)


def test_constant_and_rank_deficient_features_give_defined_values() -> None:
    y = _gauss(50, 12, 5)
    assert all(v == 0.0 for v in alignment_metrics(np.full((12, 3), 2.5), y).as_dict().values())
    assert prepare_side("X", np.zeros((12, 3))).constant
    rank1 = np.outer(_gauss(51, 12, 1)[:, 0], np.arange(1.0, 5.0))
    got = alignment_metrics(rank1, y).as_dict()
    assert all(v is not None and np.isfinite(v) for v in got.values())
    assert alignment_metrics(rank1, 2 * rank1 + 1).rho_pca == pytest.approx(1.0)


def test_invalid_inputs_are_named() -> None:
    with pytest.raises(ValueError, match="X has n=2"):
        alignment_metrics(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="Y has 1 non-finite"):
        alignment_metrics(_gauss(0, 5, 2), np.array([[np.nan, 1.0]] + [[1.0, 2.0]] * 4))
    with pytest.raises(ValueError, match="image 0: X has 5 cells but Y has 4"):
        alignment_report([(np.zeros((5, 2)), np.zeros((4, 2)))])
    with pytest.raises(ValueError, match="min_cells=2"):
        alignment_report([], min_cells=2)


def test_rho_pca_rotates_point_pca_onto_image_pca_as_in_the_paper() -> None:
    """Reference: scipy's orthogonal Procrustes of Y's 3 local PCA scores onto X's, then the
    mean channel correlation with X's scores (paper §VI-A); X onto Y gives another value."""
    from scipy.linalg import orthogonal_procrustes

    rng = np.random.default_rng(7)
    x = rng.normal(size=(60, 8)) * np.array([5.0, 3.0, 2.0, 1, 1, 1, 1, 1])
    y = np.tanh(x[:, :6] @ rng.normal(size=(6, 5))) + 0.8 * rng.normal(size=(60, 5))
    sx, sy = prepare_side("X", x), prepare_side("Y", y)
    R, _ = orthogonal_procrustes(sy.scores, sx.scores)
    aligned = sy.scores @ R
    want = np.mean([np.corrcoef(aligned[:, j], sx.scores[:, j])[0, 1] for j in range(3)])
    R2, _ = orthogonal_procrustes(sx.scores, sy.scores)
    other = np.mean([np.corrcoef((sx.scores @ R2)[:, j], sy.scores[:, j])[0, 1]
                     for j in range(3)])
    got = alignment_metrics(x, y).rho_pca
    assert got == pytest.approx(want, abs=1e-12)
    assert abs(got - other) > 1e-3  # the direction matters


# --- report edges the mutation run asked for ----------------------------------------------------


def test_report_defaults_are_twenty_permutations_and_seed_zero() -> None:
    pairs = [_planted(60, n=12)]
    report = alignment_report(pairs)
    assert (report.min_cells, report.n_perm, report.seed) == (3, 20, 0)
    assert report == alignment_report(pairs, min_cells=3, n_perm=20, seed=0)
    other = alignment_report(pairs, min_cells=5, n_perm=2, seed=3)
    assert (other.min_cells, other.n_perm, other.seed) == (5, 2, 3)


def test_null_of_each_image_comes_from_its_own_seeded_generator() -> None:
    """null macro mean of permutation j = mean over images of the metric with Y's cells in the
    order default_rng([seed, i]).permutation(n) (j-th draw)."""
    pairs = [_planted(61, n=10), _planted(62, n=12)]
    report = alignment_report(pairs, n_perm=2, seed=5)
    null = np.zeros(2)
    for i, (x, y) in enumerate(pairs):
        sx, sy = prepare_side("X", x), prepare_side("Y", y)
        rng = np.random.default_rng([5, i])
        for j in range(2):
            null[j] += metrics_from_sides(sx, permute_side(sy, rng.permutation(len(x)))).cka / 2
    assert report.metric("cka").null_mean == pytest.approx(null.mean(), rel=1e-12)
    assert report.metric("cka").null_std == pytest.approx(null.std(), rel=1e-9)


def test_report_counts_every_excluded_image_and_keeps_later_metrics_of_small_ones() -> None:
    x, y = _planted(63, n=20)
    pairs = [(x[:2], y[:2]), (x[:1], y[:1]), (np.ones((6, 2)), y[:6]), (x[:6], np.ones((6, 3))),
             (x[:3], y[:3])]
    report = alignment_report(pairs, n_perm=1)
    assert (report.n_images_seen, report.n_excluded_small, report.n_excluded_constant) == (5, 2, 2)
    assert report.metric("cka_debiased").n_images == 0  # n = 3: no unbiased HSIC
    for name in ("rho_pca", "cka", "svcca", "jaccard", "rho_aff"):
        assert report.metric(name).n_images == 1, name


def test_a_report_without_usable_images_is_all_zero_with_p_value_one() -> None:
    report = alignment_report([(np.ones((5, 2)), _gauss(0, 5, 2))], n_perm=3)
    for name in METRICS:
        m = report.metric(name)
        assert (m.name, m.value, m.null_mean, m.null_std, m.p_value, m.n_images) == (
            name, 0.0, 0.0, 0.0, 1.0, 0)


def test_p_value_counts_nulls_equal_to_the_value() -> None:
    """An equilateral triangle of cells: every permutation leaves its centred Gram matrix
    unchanged, so every null equals the value (up to rounding) and p = 1."""
    tri = np.array([[1.0, 0.0], [-0.5, np.sqrt(3) / 2], [-0.5, -np.sqrt(3) / 2]])
    report = alignment_report([(tri, tri)], n_perm=6)
    assert report.metric("cka").value == pytest.approx(1.0)
    assert report.metric("cka").p_value == 1.0


def test_rows_carry_every_column_and_bad_arguments_are_named() -> None:
    report = alignment_report([_planted(64, n=8)], n_perm=2, seed=1)
    row = report.rows()[0]
    assert set(row) == {"metric", "value", "null_value", "null_std", "p_value", "images",
                        "excluded_images", "n_images_seen", "n_excluded_small",
                        "n_excluded_constant", "n_perm", "seed"}
    m = report.metric("rho_pca")
    assert (row["value"], row["null_std"], row["p_value"]) == (m.value, m.null_std, m.p_value)
    assert (row["n_perm"], row["seed"], row["n_images_seen"]) == (2, 1, 1)
    with pytest.raises(KeyError, match="no metric 'psnr'; have"):
        report.metric("psnr")
    no_null = alignment_report([_planted(64, n=8)], n_perm=0).metric("cka")
    assert (no_null.null_mean, no_null.null_std, no_null.p_value) == (0.0, 0.0, 1.0)
    for n_perm, seed in ((-1, 0), (0, -1)):
        with pytest.raises(DataError, match=rf"^n_perm={n_perm} and seed={seed} must be >= 0$"):
            alignment_report([], n_perm=n_perm, seed=seed)
    bad = np.ones((4, 2))
    bad[1, 1] = np.nan
    with pytest.raises(DataError, match=r"^X of image 1 has 1 non-finite"):
        alignment_report([_planted(65, n=4), (bad, _gauss(1, 4, 2))])
    with pytest.raises(DataError, match=r"^Y of image 0 has 1 non-finite"):
        alignment_report([(_gauss(1, 4, 2), bad)])
