"""2D-3D alignment study (paper §VI-A, Table 1): macro averages beside a permutation null.

Per image the diagnostics of `packets.alignment_metrics` compare X (n, p) image-latent features
with Y (n, q) pooled point features on the n supported cells (n_q > 0). `alignment_report`
macro-averages them over images and, because in the paper's regime (n <= 384 cells, 1224-1536
channels) biased CKA of two *independent* Gaussian sets is already ~0.8, reports each metric
beside a null computed the same way with the cell correspondence permuted within each image.

Exclusions (counted in the report): images with fewer than `min_cells` cells, and images where
either side is constant across cells (no spatial structure; see `alignment_metrics`). Debiased
CKA is averaged only over images with n >= 4 (its own `n_images`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from packets.alignment_metrics import (
    MIN_CELLS,
    AlignmentMetrics,
    Side,
    alignment_metrics,
    metrics_from_sides,
    permute_side,
    prepare_side,
)
from schemas.errors import DataError

__all__ = [
    "METRICS",
    "AlignmentMetrics",
    "AlignmentReport",
    "MetricSummary",
    "alignment_metrics",
    "alignment_report",
]

METRICS: tuple[str, ...] = ("rho_pca", "cka", "cka_debiased", "svcca", "jaccard", "rho_aff")
"""Metric names in Table 1 order, with debiased CKA beside CKA."""


@dataclass(frozen=True)
class MetricSummary:
    """One metric over the images: macro mean, permutation null and its spread.

    value: mean over used images of the per-image metric.
    null_mean / null_std: mean and std over the n_perm permutations of the macro mean computed
        with Y's cells shuffled within each image (null_std = 0 for n_perm = 1).
    p_value: (1 + #{null macro mean >= value}) / (1 + n_perm), one-sided.
    n_images: images that contributed to this metric.
    """

    name: str
    value: float
    null_mean: float
    null_std: float
    p_value: float
    n_images: int


@dataclass(frozen=True)
class AlignmentReport:
    """Macro-averaged diagnostics of one feature pair with exclusion counts."""

    metrics: tuple[MetricSummary, ...]
    n_images_seen: int
    n_excluded_small: int
    n_excluded_constant: int
    min_cells: int
    n_perm: int
    seed: int

    def metric(self, name: str) -> MetricSummary:
        """The summary named `name` (one of METRICS)."""
        for m in self.metrics:
            if m.name == name:
                return m
        raise KeyError(f"no metric {name!r}; have {[m.name for m in self.metrics]}")

    def rows(self) -> list[dict[str, float | int | str]]:
        """One flat dict per metric; keys cover schemas.tables.ALIGNMENT except `pair`."""
        extra = {
            "excluded_images": self.n_excluded_small + self.n_excluded_constant,
            "n_images_seen": self.n_images_seen,
            "n_excluded_small": self.n_excluded_small,
            "n_excluded_constant": self.n_excluded_constant,
            "n_perm": self.n_perm,
            "seed": self.seed,
        }
        return [
            {"metric": m.name, "value": m.value, "null_value": m.null_mean,
             "null_std": m.null_std, "p_value": m.p_value, "images": m.n_images, **extra}
            for m in self.metrics
        ]


class _Accumulator:
    """Running sums of per-image metrics: observed (per metric) and null (per metric, per perm)."""

    def __init__(self, n_perm: int) -> None:
        self.total = dict.fromkeys(METRICS, 0.0)
        self.count = dict.fromkeys(METRICS, 0)
        self.null = {m: np.zeros(n_perm, dtype=np.float64) for m in METRICS}

    def add(self, observed: AlignmentMetrics, nulls: list[AlignmentMetrics]) -> None:
        """Add one image's observed metrics and its per-permutation metrics."""
        for name, value in observed.as_dict().items():
            if value is None:
                continue
            self.total[name] += value
            self.count[name] += 1
            for j, nm in enumerate(nulls):
                self.null[name][j] += float(nm.as_dict()[name] or 0.0)

    def summary(self, name: str) -> MetricSummary:
        """Macro mean, null mean/std and permutation p-value of one metric (0s if no images)."""
        c = self.count[name]
        if c == 0:
            return MetricSummary(name, 0.0, 0.0, 0.0, 1.0, 0)
        value = self.total[name] / c
        null = self.null[name] / c
        n_perm = null.size
        exceed = int(np.sum(null >= value - 1e-12))
        return MetricSummary(
            name=name,
            value=value,
            null_mean=float(null.mean()) if n_perm else 0.0,
            null_std=float(null.std()) if n_perm else 0.0,
            p_value=(1 + exceed) / (1 + n_perm),
            n_images=c,
        )


def _image_nulls(
    sx: Side, sy: Side, rng: np.random.Generator, n_perm: int
) -> list[AlignmentMetrics]:
    """Metrics of one image with Y's cells permuted, n_perm times (identity draws are kept)."""
    n = sx.gram.shape[0]
    return [metrics_from_sides(sx, permute_side(sy, rng.permutation(n))) for _ in range(n_perm)]


def alignment_report(
    pairs: Iterable[tuple[npt.ArrayLike, npt.ArrayLike]],
    min_cells: int = MIN_CELLS,
    n_perm: int = 20,
    seed: int = 0,
) -> AlignmentReport:
    """Macro-average the diagnostics over images, each beside its within-image permutation null.

    pairs: per image (X (n, p), Y (n, q)) features on the same n supported cells, any float dtype
        (computed in float64). Streamed: one image is held at a time.
    min_cells: images with n < min_cells are excluded and counted (paper: 3); must be >= 3.
    n_perm: permutations per image for the null (>= 0; 0 gives null 0 and p-value 1).
    seed: the permutation of image i comes from default_rng([seed, i]), so reports are
        reproducible and independent of how many permutations earlier images drew.
    """
    if min_cells < MIN_CELLS:
        raise DataError(f"min_cells={min_cells} must be >= {MIN_CELLS}")
    if n_perm < 0 or seed < 0:
        raise DataError(f"n_perm={n_perm} and seed={seed} must be >= 0")
    acc = _Accumulator(n_perm)
    seen = small = constant = 0
    for i, (x, y) in enumerate(pairs):
        seen += 1
        n_x, n_y = np.shape(x)[0], np.shape(y)[0]
        if n_x != n_y:
            raise DataError(f"image {i}: X has {n_x} cells but Y has {n_y}")
        if n_x < min_cells:
            small += 1
            continue
        sx, sy = prepare_side(f"X of image {i}", x), prepare_side(f"Y of image {i}", y)
        if sx.constant or sy.constant:
            constant += 1
            continue
        rng = np.random.default_rng([seed, i])
        acc.add(metrics_from_sides(sx, sy), _image_nulls(sx, sy, rng, n_perm))
    return AlignmentReport(
        metrics=tuple(acc.summary(m) for m in METRICS),
        n_images_seen=seen,
        n_excluded_small=small,
        n_excluded_constant=constant,
        min_cells=min_cells,
        n_perm=n_perm,
        seed=seed,
    )
