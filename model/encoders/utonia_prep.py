"""Pre- and post-processing of the Utonia point encoder, as pure array functions.

Follows the Utonia README (github.com/Pointcept/Utonia) for outdoor LiDAR: input dict of
`coord`, `color`, `normal` (missing modalities zeros), coordinates multiplied by `scale`
(0.2 outdoors; no centre shift, the sensor stays at the origin), grid sampling at 0.01 of
the scaled coordinates with the inverse map kept, features `feat` = [coord, color, normal]
(9 channels). After the network, features are unpooled from the coarsest stage: the first
`n_concat` upcasts concatenate [parent feature, child feature], the rest copy, and the
grid-sampling inverse maps the result back to every input point. With Utonia's stage widths
(..., 216, 432, 576) and n_concat = 2 that is 216 + 432 + 576 = 1224 channels.

One deliberate difference: Utonia's GridSample(mode="train") keeps a *random* point per
voxel; here the first point (lowest input index) is kept, so the encoder is deterministic.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from schemas.errors import DataError

OUTDOOR_SCALE = 0.2
GRID_SIZE = 0.01


@dataclass(frozen=True)
class UtoniaInput:
    """Grid-sampled network input for one sweep (M sampled of N input points)."""

    coord: np.ndarray       # (M, 3) float32, scaled coordinates of the kept points
    grid_coord: np.ndarray  # (M, 3) int64, voxel indices shifted to start at 0
    feat: np.ndarray        # (M, 9) float32, [coord, color, normal]
    inverse: np.ndarray     # (N,) int64, input point -> kept point (its voxel)

    def as_dict(self) -> dict[str, np.ndarray]:
        """Arrays under Utonia's key names, with `offset` = [M] (one cloud in the batch)."""
        return {"coord": self.coord, "grid_coord": self.grid_coord, "feat": self.feat,
                "offset": np.array([len(self.coord)], np.int64), "inverse": self.inverse}


def input_dict(xyz: np.ndarray, color: np.ndarray | None = None,
               normal: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Utonia's raw input: coord (N, 3) float32 and color, normal (N, 3), zeros if missing."""
    coord = np.asarray(xyz, np.float32).reshape(-1, 3)
    zeros = np.zeros_like(coord)
    return {"coord": coord,
            "color": zeros if color is None else np.asarray(color, np.float32),
            "normal": zeros if normal is None else np.asarray(normal, np.float32)}


def grid_sample(coord: np.ndarray,
                grid_size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Keep one point per voxel of edge `grid_size`.

    coord: (N, 3) float. Returns keep (M,) int64 indices of the first input point of each
    voxel, inverse (N,) int64 with keep[inverse] in the same voxel as every input point, and
    grid_coord (M, 3) int64 voxel indices minus their minimum.
    """
    cell = np.floor(np.asarray(coord, np.float64) / grid_size).astype(np.int64)
    if len(cell) == 0:
        empty = np.zeros(0, np.int64)
        return empty, empty, np.zeros((0, 3), np.int64)
    cell -= cell.min(axis=0)
    _, keep, inverse = np.unique(cell, axis=0, return_index=True, return_inverse=True)
    return keep.astype(np.int64), inverse.reshape(-1).astype(np.int64), cell[keep]


def prepare(xyz: np.ndarray, *, scale: float = OUTDOOR_SCALE, grid_size: float = GRID_SIZE,
            color: np.ndarray | None = None, normal: np.ndarray | None = None) -> UtoniaInput:
    """Scale, grid-sample and assemble the network input of one sweep (N, 3) metres."""
    raw = input_dict(xyz, color, normal)
    coord = raw["coord"] * np.float32(scale)
    keep, inverse, grid_coord = grid_sample(coord, grid_size)
    kept = coord[keep]
    color01 = raw["color"][keep] / np.float32(255.0)  # Utonia's NormalizeColor
    feat = np.concatenate([kept, color01, raw["normal"][keep]], axis=1).astype(np.float32)
    return UtoniaInput(kept, grid_coord, feat, inverse)


def unpool_concat(feats: Sequence[Any], inverses: Sequence[Any], n_concat: int) -> Any:
    """Map stage features back to the finest stage, concatenating the last upcasts.

    feats[k]: (M_k, C_k) features of stage k (0 = finest, L = coarsest), numpy or torch;
    inverses[k - 1]: (M_{k-1},) int, stage-(k-1) point -> its stage-k parent cell, k = 1..L.
    The first `n_concat` steps from the coarsest stage concatenate [parent, child], the rest
    copy the child features. Returns (M_0, C_L + ... + C_{L-n_concat}).
    """
    levels = len(feats) - 1
    if len(inverses) != levels or not 0 <= n_concat <= levels:
        raise DataError(f"unpool: {len(feats)} stages, {len(inverses)} inverses, "
                         f"n_concat={n_concat}")
    out = feats[levels]
    for step, k in enumerate(range(levels, 0, -1)):
        child = out[inverses[k - 1]]
        out = _cat(feats[k - 1], child) if step < n_concat else child
    return out


def _cat(a: Any, b: Any) -> Any:
    if isinstance(a, np.ndarray):
        return np.concatenate([a, b], axis=1)
    import torch

    return torch.cat([a, b], dim=-1)


def pooling_chain(point: Any) -> tuple[list[Any], list[Any]]:
    """Walk Utonia's output `Point` (coarsest first) down `pooling_parent` links.

    Returns (feats finest..coarsest, inverses) in the form `unpool_concat` takes.
    """
    feats, inverses = [point.feat], []
    while "pooling_parent" in point:
        inverses.append(point["pooling_inverse"])
        point = point["pooling_parent"]
        feats.append(point.feat)
    return feats[::-1], inverses[::-1]


def concat_width(enc_channels: Sequence[int], n_concat: int) -> int:
    """Channels of `unpool_concat` output for encoder stage widths `enc_channels`."""
    return int(sum(enc_channels[len(enc_channels) - 1 - n_concat:]))
