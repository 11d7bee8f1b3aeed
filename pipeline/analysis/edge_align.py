"""The edge maps and the rotation search of the LiDAR edge alignment (`packets.edges` holds
the edge points and the score): an image's band-passed edge strength (OpenCV filters, so not
in the pure `packets` layer) and the coarse-to-fine search of the rotation that maximises
`packets.edges.alignment_score`. Every array is float64.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from packets.edges import EdgeView, alignment_score

F64 = npt.NDArray[np.float64]

BACKGROUND_SCALE = 4.0
"""The edge map is band-passed: less the gradient blurred this many times wider."""


def edge_map(grey: npt.ArrayLike, sigma_px: float) -> F64:
    """Edge strength (h, w, 2) of a grey image (h, w) (any scale): the absolute Sobel
    derivatives along u and v, divided by the mean gradient magnitude (so every view weighs
    alike), band-passed (blurred by a Gaussian of `sigma_px` pixels, 0: unblurred, less a
    `BACKGROUND_SCALE` times wider blur: a point scores how much more edge it sits on than its
    surroundings, so textured regions add no trend); all zero for a flat image."""
    img = np.asarray(grey, np.float64)
    gx = cv2.Sobel(img, cv2.CV_64F, 1, 0, ksize=3)
    gy = cv2.Sobel(img, cv2.CV_64F, 0, 1, ksize=3)
    mag = np.stack([np.abs(gx), np.abs(gy)], -1)
    mean = float(np.hypot(gx, gy).mean())
    if mean <= 0:
        return np.zeros_like(mag)
    mag /= mean
    fine = cv2.GaussianBlur(mag, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT) \
        if sigma_px > 0 else mag
    coarse = cv2.GaussianBlur(mag, (0, 0), BACKGROUND_SCALE * max(sigma_px, 1.0),
                              borderType=cv2.BORDER_REFLECT)
    out: F64 = np.asarray(fine - coarse, np.float64)
    return out


def _refine(xs: F64, ys: F64) -> float:
    """The grid maximum refined by a parabola through it and its neighbours."""
    i = int(np.argmax(ys))
    if 0 < i < len(xs) - 1:
        y0, y1, y2 = ys[i - 1:i + 2]
        den = y0 - 2 * y1 + y2
        if den < 0:
            return float(xs[i] + 0.5 * (y0 - y2) / den * (xs[i + 1] - xs[i]))
    return float(xs[i])


@dataclass(frozen=True)
class EdgeEstimate:
    """Rotation vector (3,) rad maximising the score, the score at zero and at it, and the
    number of edge points used."""

    rotation_rad: tuple[float, float, float]
    score_nominal: float
    score_max: float
    points: int


def align_rotation(views: Sequence[EdgeView], max_rad: float,
                   sigmas_px: Sequence[float] = (4.0, 2.0, 1.0, 0.5), steps: int = 9,
                   rounds: int = 3) -> EdgeEstimate:
    """Coarse-to-fine coordinate ascent of the alignment score over rotations within
    +-`max_rad` per axis: for each blur in `sigmas_px` (wide first), `rounds` passes over the
    three axes, each a grid of `steps` angles about the current value (the span halving at
    every level), the best parabola-refined."""
    r = np.zeros(3)
    span = max_rad
    for sigma in sigmas_px:
        maps = [edge_map(v.grey, sigma) for v in views]
        for _ in range(rounds):
            for k in range(3):
                grid = r[k] + np.linspace(-span, span, steps)
                ys = np.array([alignment_score(views, maps, np.where(np.arange(3) == k, a, r))
                               for a in grid])
                r[k] = float(np.clip(_refine(grid, ys), -max_rad, max_rad))
        span /= 2
    maps = [edge_map(v.grey, sigmas_px[-1]) for v in views]
    return EdgeEstimate((float(r[0]), float(r[1]), float(r[2])),
                        alignment_score(views, maps, np.zeros(3)),
                        alignment_score(views, maps, r),
                        int(sum(len(v.points) for v in views)))
