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
BASE_T = np.array([_TABLE[m][0] for m in MATERIALS], dtype=np.float32).T.copy()  # (3, M)
INV_CELL = np.array([1.0 / _TABLE[m][1] for m in MATERIALS], dtype=np.float32)
CHECK = np.array([_TABLE[m][2] for m in MATERIALS], dtype=np.float32)
WAVE = np.array([_TABLE[m][3] for m in MATERIALS], dtype=np.float32)
REFLECTIVITY = np.array([_TABLE[m][4] for m in MATERIALS], dtype=np.float32)
_WAVES = np.random.default_rng(12345).normal(size=(3, 3)).astype(np.float32) * 2.5  # (3 xyz, 3)
_MAT_PHASE = np.float32(1.7)  # phase shift per material index
SKY_TOP = np.array([0.45, 0.62, 0.9], dtype=np.float32)
SKY_HORIZON = np.array([0.85, 0.88, 0.92], dtype=np.float32)


def rotate_soa(R: npt.NDArray[np.floating], v: F32) -> F32:
    """R @ v for vectors stored as rows x, y, z: v (3, N) float32 -> (3, N) float32.

    Structure-of-arrays keeps every pass contiguous (a BLAS call on thin (N, 3) operands is
    slow on a loaded machine)."""
    R = np.asarray(R, dtype=np.float32)
    out = np.empty_like(v)
    for i in range(3):
        np.multiply(v[0], R[i, 0], out=out[i])
        out[i] += R[i, 1] * v[1]
        out[i] += R[i, 2] * v[2]
    return out


def albedo(p: F32, material: I64) -> F32:
    """RGB albedo (3, N) float32 in [0, 1] at world points p (3, N) m, materials (N,) >= 0."""
    m = material
    inv = INV_CELL[m]
    parity = np.floor(p[0] * inv + 0.5).astype(np.int32)  # + 0.5: no boundary on z = 0
    parity += np.floor(p[1] * inv + 0.5).astype(np.int32)
    parity += np.floor(p[2] * inv + 0.5).astype(np.int32)
    gain = 1.0 + CHECK[m] * (2 * (parity & 1) - 1).astype(np.float32)
    phase = rotate_soa(_WAVES.T, p)
    phase += m.astype(np.float32) * _MAT_PHASE
    waves = np.sin(phase, out=phase)  # (3, N)
    gain *= 1.0 + WAVE[m] * 0.5 * (waves[0] + waves[1] + waves[2])
    rgb = BASE_T[:, m]  # (3, N)
    rgb *= 1.0 + 0.12 * waves
    rgb *= gain
    return np.clip(rgb, 0.0, 1.0, out=rgb)


def shade(p: F32, normals: F32, material: I64, dirs_z: F32) -> F32:
    """Colour (3, N) float32 in [0, 1]: shaded albedo where material >= 0, sky where it is -1.

    p: world points (3, N); normals: (N, 3) from the raycaster; dirs_z: world z of the unit ray
    directions (N,) (for the sky gradient only)."""
    hit = material >= 0
    sun = SUN.astype(np.float32)
    lam = normals[:, 0] * sun[0] + normals[:, 1] * sun[1] + normals[:, 2] * sun[2]
    lam = np.nan_to_num(np.abs(lam))
    out = albedo(p, np.where(hit, material, 0))
    out *= 0.35 + 0.65 * lam
    up = np.clip(dirs_z, 0.0, 1.0)
    for c in range(3):
        sky = SKY_HORIZON[c] + (SKY_TOP[c] - SKY_HORIZON[c]) * up
        np.copyto(out[c], sky, where=~hit)
    return out


def to_bgr8(rgb: F32, height: int, width: int) -> U8:
    """Float RGB (3, H*W) in [0, 1] -> uint8 BGR image (H, W, 3) (OpenCV order)."""
    q = (np.clip(rgb, 0, 1) * 255.0 + 0.5).astype(np.uint8)
    return np.ascontiguousarray(q[::-1].T.reshape(height, width, 3))


def intensity(material: I64, cos_incidence: F32) -> F32:
    """LiDAR intensity (N,) float32 in [0, 255] from reflectivity and |cos incidence|."""
    return np.clip(
        255.0 * REFLECTIVITY[material] * (0.2 + 0.8 * np.abs(cos_incidence)), 0, 255
    ).astype(np.float32)
