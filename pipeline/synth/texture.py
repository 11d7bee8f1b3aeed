"""Surface colour and LiDAR reflectivity as deterministic functions of world position and material.

Colour depends only on the hit point, its material and its surface normal (Lambert shading under
a fixed sun), never on the viewer, so every view of one surface agrees. The pattern is a 3-D
checker plus a few plane waves per material (cheap, vectorized).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from pipeline.synth.scene import MATERIALS

F32 = npt.NDArray[np.float32]
I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]

SUN = np.array([0.35, 0.25, 0.9]) / np.linalg.norm([0.35, 0.25, 0.9])
# base RGB in [0, 1], checker cell (m), checker contrast, wave contrast, LiDAR reflectivity
_TABLE = {
    "ground": ((0.45, 0.42, 0.38), 1.0, 0.18, 0.20, 0.25),
    "wall": ((0.78, 0.74, 0.66), 0.5, 0.10, 0.25, 0.55),
    "box": ((0.62, 0.45, 0.25), 0.25, 0.22, 0.20, 0.45),
    "pillar": ((0.60, 0.62, 0.66), 0.3, 0.15, 0.15, 0.60),
    "trunk": ((0.35, 0.24, 0.14), 0.2, 0.20, 0.30, 0.35),
    "canopy": ((0.22, 0.48, 0.18), 0.4, 0.25, 0.35, 0.30),
    "ceiling": ((0.88, 0.88, 0.85), 1.2, 0.08, 0.10, 0.70),
    "facade": ((0.70, 0.55, 0.48), 1.5, 0.20, 0.25, 0.50),
}
BASE = np.array([_TABLE[m][0] for m in MATERIALS], dtype=np.float32)
CELL = np.array([_TABLE[m][1] for m in MATERIALS], dtype=np.float32)
CHECK = np.array([_TABLE[m][2] for m in MATERIALS], dtype=np.float32)
WAVE = np.array([_TABLE[m][3] for m in MATERIALS], dtype=np.float32)
REFLECTIVITY = np.array([_TABLE[m][4] for m in MATERIALS], dtype=np.float32)
_WAVES = np.random.default_rng(12345).normal(size=(len(MATERIALS), 3, 3)).astype(np.float32) * 2.5
_PHASE = np.random.default_rng(54321).uniform(0, 2 * np.pi, (len(MATERIALS), 3)).astype(np.float32)
SKY_TOP = np.array([0.45, 0.62, 0.9], dtype=np.float32)
SKY_HORIZON = np.array([0.85, 0.88, 0.92], dtype=np.float32)


def albedo(points: F32, material: I64) -> F32:
    """RGB albedo (N, 3) float32 in [0, 1] at world points (N, 3) m with materials (N,) >= 0."""
    cell = CELL[material][:, None]  # + 0.5: no cell boundary on the planes z = 0 or x = k * cell
    parity = np.floor(points / cell + 0.5).astype(np.int64).sum(axis=1) & 1
    check = 1.0 + CHECK[material] * (2 * parity - 1)
    phase = np.einsum("nk,njk->nj", points, _WAVES[material]) + _PHASE[material]  # (N, 3)
    wave = 1.0 + WAVE[material] * np.sin(phase).mean(axis=1) * 1.5
    tint = 1.0 + 0.12 * np.sin(phase)  # per channel
    rgb = BASE[material] * (check * wave)[:, None] * tint
    return np.clip(rgb, 0.0, 1.0).astype(np.float32)


def shade(points: F32, normals: F32, material: I64, dirs: F32) -> F32:
    """Colour (N, 3) float32 in [0, 1]: shaded albedo where material >= 0, sky where it is -1.

    `dirs` (N, 3) are the unit ray directions (only used for the sky gradient)."""
    out = np.empty(points.shape, dtype=np.float32)
    hit = material >= 0
    if hit.any():
        lam = np.abs(normals[hit] @ SUN.astype(np.float32))
        out[hit] = albedo(points[hit], material[hit]) * (0.35 + 0.65 * lam)[:, None]
    if (~hit).any():
        up = np.clip(dirs[~hit, 2], 0.0, 1.0)[:, None]
        out[~hit] = SKY_HORIZON * (1 - up) + SKY_TOP * up
    return out


def to_bgr8(rgb: F32) -> U8:
    """Float RGB in [0, 1] (..., 3) -> uint8 BGR (OpenCV order)."""
    return np.ascontiguousarray((np.clip(rgb, 0, 1) * 255.0 + 0.5).astype(np.uint8)[..., ::-1])


def intensity(material: I64, cos_incidence: F32) -> F32:
    """LiDAR intensity (N,) float32 in [0, 255] from reflectivity and |cos incidence|."""
    return np.clip(
        255.0 * REFLECTIVITY[material] * (0.2 + 0.8 * np.abs(cos_incidence)), 0, 255
    ).astype(np.float32)
