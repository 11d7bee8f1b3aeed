"""The z-score of an observed statistic against a null's mean and standard deviation (pure
math), shared by the geometry verdict (`packets.geometry_verdict`) and the cross-view
consistency (`packets.view_overlap`), which both read their scores against one null."""

from __future__ import annotations

import numpy as np


def z_score(observed: float, mean: float, std: float) -> float:
    """(observed - mean) / std; with std 0: +inf above the mean, 0 at it, -inf below."""
    if std > 0:
        return (observed - mean) / std
    return 0.0 if observed == mean else float(np.copysign(np.inf, observed - mean))
