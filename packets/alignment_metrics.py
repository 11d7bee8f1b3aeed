"""Per-image 2D-3D alignment diagnostics of the paper's Table 1 (§VI-A), float64 throughout.

Inputs per image: X (n, p) image-latent features and Y (n, q) pooled point features on the same
n supported cells (row i of X and row i of Y describe the same cell). All metrics compare the
*spatial relations across cells*, so p != q is fine.

Each side is reduced once to a `Side` summary (PCA scores, SVD basis, Gram and cosine-affinity
matrices); metrics are computed from two summaries. Permuting a summary's cells is exact
(`permute_side`), which is how the permutation null is computed "the same way" as the value.

Cost: the n x n Gram/affinity matrices make one image O(n^2 (p + q) + n^3); fine for the
n <= 384 cells of a 16 x 24 grid, not meant for thousands of rows. Run with one BLAS thread per
process (OPENBLAS_NUM_THREADS=1) on shared machines: oversubscribed BLAS threads were much
slower (docs/benchmarks.md, 'Design measurements').

Degenerate inputs (documented behaviour, never NaN):
- A side with no variance across cells (all rows equal up to 1e-10 relative) has no spatial
  structure: every metric of that pair is 0.0 (`alignment_report` excludes such images and
  counts them).
- Numerical rank counts Gram eigenvalues above lambda_max * max(n, p) * eps (singular values
  below ~sqrt(max(n, p) eps) ~ 6e-7 of the largest count as zero). Rank-deficient sides use
  the available rank: rho_PCA uses k = min(3, rank_X, rank_Y)
  components, SVCCA keeps min(20, rank) directions per side.
- Rows with zero norm have cosine 0 to every other row.
- A correlation whose input has zero variance is 0.0.
- Debiased CKA needs n >= 4 (the unbiased HSIC divides by n - 3); it is None for n = 3.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from packets._checks import require_finite
from schemas.errors import DataError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

PCA_COMPONENTS: int = 3
SVCCA_DIMS: int = 20
KNN_K: int = 10
MIN_CELLS: int = 3
_CONST_RTOL: float = 1e-10


@dataclass(frozen=True)
class Side:
    """One image's features on its n supported cells, reduced for the metrics.

    scores: (n, <=3) float64 local PCA scores (centred data on its top principal axes).
    basis: (n, d) float64 orthonormal left singular vectors of the centred data, d = min(20, rank).
    gram: (n, n) float64 Gram matrix of the centred features (linear kernel).
    gram_u: (n, n) float64 Gram matrix after unbiased (U-statistic) centring; zero diagonal.
    affinity: (n, n) float64 cosine affinity of the raw feature rows.
    knn: (n, n) bool; row i marks the min(10, n - 1) cells most cosine-similar to cell i
        (self excluded; ties go to the lower cell index at preparation time).
    rank: numerical rank of the centred data.
    constant: True when all rows are equal (no spatial structure).
    """

    scores: F64
    basis: F64
    gram: F64
    gram_u: F64
    affinity: F64
    knn: npt.NDArray[np.bool_]
    rank: int
    constant: bool


@dataclass(frozen=True)
class AlignmentMetrics:
    """Diagnostics of one image; all in [-1, 1] except where noted (Jaccard in [0, 1])."""

    rho_pca: float
    cka: float
    cka_debiased: float | None
    svcca: float
    jaccard: float
    rho_aff: float

    def as_dict(self) -> dict[str, float | None]:
        """Metric name -> value."""
        return {
            "rho_pca": self.rho_pca,
            "cka": self.cka,
            "cka_debiased": self.cka_debiased,
            "svcca": self.svcca,
            "jaccard": self.jaccard,
            "rho_aff": self.rho_aff,
        }


def _as_features(name: str, x: npt.ArrayLike) -> F64:
    """Validate (n, p) finite features with n >= 3 and p >= 1; return float64 copy."""
    arr = np.array(x, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] < 1:
        raise DataError(f"{name} must be a 2-D (n, channels) array, got shape {arr.shape}")
    if arr.shape[0] < MIN_CELLS:
        raise DataError(f"{name} has n={arr.shape[0]} cells; the diagnostics need >= {MIN_CELLS}")
    require_finite(name, arr)
    return arr


def _unbiased_centre(gram: F64) -> F64:
    """U-statistic centring of an (n, n) Gram matrix (Song et al. 2012; Nguyen et al. 2021)."""
    n = gram.shape[0]
    g = gram.copy()
    np.fill_diagonal(g, 0.0)
    if n < 4:
        return np.zeros_like(g)
    means = g.sum(axis=0) / (n - 2)
    means -= means.sum() / (2 * (n - 1))
    g -= means[:, None]
    g -= means[None, :]
    np.fill_diagonal(g, 0.0)
    return g


def _cosine_affinity(x: F64) -> F64:
    """(n, n) cosine similarity of rows; zero-norm rows give 0."""
    norms = np.linalg.norm(x, axis=1)
    safe = np.where(norms > 0.0, norms, 1.0)
    unit = x / safe[:, None]
    return np.clip(unit @ unit.T, -1.0, 1.0)


def prepare_side(name: str, x: npt.ArrayLike) -> Side:
    """Reduce (n, p) features of one image to a `Side`; `name` labels errors."""
    arr = _as_features(name, x)
    xc = arr - arr.mean(axis=0, keepdims=True)
    scale = float(np.linalg.norm(arr))
    constant = bool(np.linalg.norm(xc) <= _CONST_RTOL * scale) or scale == 0.0
    gram = xc @ xc.T
    affinity = _cosine_affinity(arr)
    lam, vec = np.linalg.eigh(gram)  # ascending; the n x n eigh beats an SVD (benchmarks.md)
    lam, u = np.clip(lam[::-1], 0.0, None), vec[:, ::-1]
    tol = float(lam[0]) * max(xc.shape) * np.finfo(np.float64).eps
    rank = 0 if constant else int(np.sum(lam > tol))
    s = np.sqrt(lam)
    k = min(PCA_COMPONENTS, rank)
    return Side(
        scores=u[:, :k] * s[:k],
        basis=u[:, : min(SVCCA_DIMS, rank)],
        gram=gram,
        gram_u=_unbiased_centre(gram),
        affinity=affinity,
        knn=knn_sets(affinity, min(KNN_K, arr.shape[0] - 1)),
        rank=rank,
        constant=constant,
    )


def permute_side(side: Side, perm: I64) -> Side:
    """The same side with its cells reordered: row i of the result is old row perm[i]."""
    ix = np.ix_(perm, perm)
    return replace(
        side,
        scores=side.scores[perm],
        basis=side.basis[perm],
        gram=side.gram[ix],
        gram_u=side.gram_u[ix],
        affinity=side.affinity[ix],
        knn=side.knn[ix],
    )


def _safe_corr(a: F64, b: F64) -> float:
    """Pearson correlation of two 1-D arrays; 0.0 if either has no variance."""
    ac, bc = a - a.mean(), b - b.mean()
    na, nb = float(np.linalg.norm(ac)), float(np.linalg.norm(bc))
    tiny = 1e-12
    if na <= tiny * max(float(np.abs(a).max()), 1e-300) * np.sqrt(a.size) or na == 0.0:
        return 0.0
    if nb <= tiny * max(float(np.abs(b).max()), 1e-300) * np.sqrt(b.size) or nb == 0.0:
        return 0.0
    return float(np.clip(ac @ bc / (na * nb), -1.0, 1.0))


def _cosine_of(a: F64, b: F64) -> float:
    """<a, b> / (|a| |b|) of flattened (contiguous) matrices; 0.0 if either is zero."""
    va, vb = a.reshape(-1), b.reshape(-1)
    na, nb = float(np.sqrt(va @ va)), float(np.sqrt(vb @ vb))
    if na == 0.0 or nb == 0.0:
        return 0.0
    return float(np.clip((va @ vb) / (na * nb), -1.0, 1.0))


def rho_pca_sides(sx: Side, sy: Side) -> float:
    """Mean per-channel correlation of local PCA scores after orthogonal Procrustes of Y onto X.

    As the paper (§VI-A, Fig. 4): the point-feature (Utonia, Y) PCA coordinates are rotated
    onto the image-latent (DA3, X) ones, R = argmin ||Y R - X|| over orthogonal R, and the
    channels of Y R are correlated with X's. Not symmetric in X and Y.
    """
    k = min(sx.scores.shape[1], sy.scores.shape[1])
    if k == 0:
        return 0.0
    a, b = sx.scores[:, :k], sy.scores[:, :k]
    u, _, vt = np.linalg.svd(b.T @ a)
    aligned = b @ (u @ vt)
    return float(np.mean([_safe_corr(aligned[:, j], a[:, j]) for j in range(k)]))


def cka_sides(sx: Side, sy: Side) -> float:
    """Biased linear CKA: <HKH, HLH> / (|HKH| |HLH|) on centred Gram matrices."""
    return _cosine_of(sx.gram, sy.gram)


def cka_debiased_sides(sx: Side, sy: Side) -> float | None:
    """Debiased linear CKA from the unbiased HSIC estimator; None for n < 4."""
    if sx.gram.shape[0] < 4:
        return None
    return _cosine_of(sx.gram_u, sy.gram_u)


def svcca_sides(sx: Side, sy: Side) -> float:
    """Mean canonical correlation between the top-min(20, rank) SVD subspaces of each side."""
    if sx.basis.shape[1] == 0 or sy.basis.shape[1] == 0:
        return 0.0
    rho = np.linalg.svd(sx.basis.T @ sy.basis, compute_uv=False)
    return float(np.clip(rho, 0.0, 1.0).mean())


def knn_sets(affinity: F64, k: int) -> npt.NDArray[np.bool_]:
    """(n, n) bool membership of each row's k most cosine-similar other rows (ties: lower index)."""
    n = affinity.shape[0]
    sim = affinity.copy()
    np.fill_diagonal(sim, -np.inf)
    order = np.argsort(-sim, axis=1, kind="stable")[:, :k]
    member = np.zeros((n, n), dtype=np.bool_)
    np.put_along_axis(member, order, True, axis=1)
    return member


def jaccard_sides(sx: Side, sy: Side) -> float:
    """Mean over cells of the Jaccard index of cosine k-NN sets, k = min(10, n - 1)."""
    kk = int(sx.knn[0].sum())
    inter = np.sum(sx.knn & sy.knn, axis=1)
    return float(np.mean(inter / (2 * kk - inter)))


def affinity_corr_sides(sx: Side, sy: Side) -> float:
    """Pearson correlation of the off-diagonal (upper-triangle) cosine affinities."""
    iu = np.triu_indices(sx.affinity.shape[0], k=1)
    return _safe_corr(sx.affinity[iu], sy.affinity[iu])


def metrics_from_sides(sx: Side, sy: Side) -> AlignmentMetrics:
    """All diagnostics of one image from its two prepared sides (0.0 if either is constant)."""
    if sx.gram.shape != sy.gram.shape:
        raise DataError(f"cell counts differ: X has {sx.gram.shape[0]}, Y has {sy.gram.shape[0]}")
    if sx.constant or sy.constant:
        zero_d = 0.0 if sx.gram.shape[0] >= 4 else None
        return AlignmentMetrics(0.0, 0.0, zero_d, 0.0, 0.0, 0.0)
    return AlignmentMetrics(
        rho_pca=rho_pca_sides(sx, sy),
        cka=cka_sides(sx, sy),
        cka_debiased=cka_debiased_sides(sx, sy),
        svcca=svcca_sides(sx, sy),
        jaccard=jaccard_sides(sx, sy),
        rho_aff=affinity_corr_sides(sx, sy),
    )


def alignment_metrics(x: npt.ArrayLike, y: npt.ArrayLike) -> AlignmentMetrics:
    """All diagnostics of one image: X (n, p) image features vs Y (n, q) point features."""
    sx, sy = prepare_side("X", x), prepare_side("Y", y)
    return metrics_from_sides(sx, sy)
