"""Mergeable per-channel statistics (count, mean, M2, min, max) in float64.

Chan et al.'s parallel-variance merge makes a tree reduction over shards exact up
to rounding: merging the statistics of two halves equals the statistics of the
whole. Used for per-channel latent normalization.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from schemas.errors import DataError

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class ChannelStats:
    """Statistics of C channels: count (scalar), mean, M2, min, max each (C,) float64."""

    count: int
    mean: F64
    m2: F64
    minimum: F64
    maximum: F64

    @classmethod
    def empty(cls, channels: int) -> ChannelStats:
        """Statistics of no samples."""
        zeros = np.zeros(channels, np.float64)
        return cls(0, zeros, zeros.copy(), np.full(channels, np.inf), np.full(channels, -np.inf))

    @classmethod
    def of(cls, x: NDArray[np.floating] | NDArray[np.integer]) -> ChannelStats:
        """Statistics of samples x (N, C), computed two-pass in float64."""
        data = np.asarray(x, dtype=np.float64)
        if data.ndim != 2:
            raise DataError(f"expected samples of shape (N, C), got {data.shape}")
        if not np.all(np.isfinite(data)):
            raise DataError("samples contain NaN or Inf")
        if data.shape[0] == 0:
            return cls.empty(data.shape[1])
        mean = data.mean(axis=0)
        m2 = ((data - mean) ** 2).sum(axis=0)
        return cls(data.shape[0], mean, m2, data.min(axis=0), data.max(axis=0))

    def merge(self, other: ChannelStats) -> ChannelStats:
        """Statistics of the union of both sample sets (parallel-variance formula)."""
        if self.count == 0:
            return other
        if other.count == 0:
            return self
        n = self.count + other.count
        delta = other.mean - self.mean
        mean = self.mean + delta * (other.count / n)
        m2 = self.m2 + other.m2 + delta**2 * (self.count * other.count / n)
        return ChannelStats(
            n, mean, m2, np.minimum(self.minimum, other.minimum),
            np.maximum(self.maximum, other.maximum),
        )

    @property
    def variance(self) -> F64:
        """Population variance per channel (0 for fewer than 2 samples)."""
        if self.count < 2:
            return np.zeros_like(self.mean)
        return np.maximum(self.m2 / self.count, 0.0)

    @property
    def std(self) -> F64:
        """Population standard deviation per channel, floored at 1e-6 for normalization."""
        return np.maximum(np.sqrt(self.variance), 1e-6)

    def to_dict(self) -> dict[str, list[float]]:
        """JSON-compatible form (for Zarr attributes)."""
        return {
            "count": [float(self.count)],
            "mean": self.mean.tolist(),
            "m2": self.m2.tolist(),
            "min": self.minimum.tolist(),
            "max": self.maximum.tolist(),
        }

    @classmethod
    def from_dict(cls, raw: dict[str, list[float]]) -> ChannelStats:
        """Inverse of `to_dict`."""
        return cls(
            int(raw["count"][0]), np.asarray(raw["mean"], np.float64),
            np.asarray(raw["m2"], np.float64), np.asarray(raw["min"], np.float64),
            np.asarray(raw["max"], np.float64),
        )


def merge_all(parts: list[ChannelStats]) -> ChannelStats:
    """Pairwise tree merge of many partial statistics."""
    if not parts:
        raise DataError("no statistics to merge")
    level = list(parts)
    while len(level) > 1:
        level = [level[i].merge(level[i + 1]) if i + 1 < len(level) else level[i]
                 for i in range(0, len(level), 2)]
    return level[0]
