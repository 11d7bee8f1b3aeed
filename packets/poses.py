"""Rigid transforms and pose interpolation: 4x4 helpers, quaternions, slerp.

Conventions: `T_a_b` (4, 4) float64 maps points from frame b into frame a. Quaternions are
ROS order (x, y, z, w), unit norm. Stamps are int64 nanoseconds; only differences are turned
into float seconds. Interpolation is linear in position and slerp in rotation; it never
extrapolates.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from packets._checks import require_finite, require_shape
from schemas.errors import DataError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]

_SLERP_LINEAR_DOT: float = 1.0 - 1e-12
"""Above this |cos(angle)| slerp falls back to normalized lerp (sin(angle) ~ 0)."""


def make_T(R: npt.ArrayLike, t: npt.ArrayLike) -> F64:
    """(..., 4, 4) transforms from rotations (..., 3, 3) and translations (..., 3)."""
    rot = np.asarray(R, dtype=np.float64)
    trans = np.asarray(t, dtype=np.float64)
    out = np.zeros((*rot.shape[:-2], 4, 4), dtype=np.float64)
    out[..., :3, :3] = rot
    out[..., :3, 3] = trans
    out[..., 3, 3] = 1.0
    return out


def invert_T(T: npt.ArrayLike) -> F64:
    """Inverse of rigid (..., 4, 4) transforms: T_b_a from T_a_b, exact for rotations."""
    mat = np.asarray(T, dtype=np.float64)
    rot_t = np.swapaxes(mat[..., :3, :3], -1, -2)
    trans = -np.einsum("...ij,...j->...i", rot_t, mat[..., :3, 3])
    return make_T(rot_t, trans)


def compose(*Ts: npt.ArrayLike) -> F64:
    """Product T_0 @ T_1 @ ... of (..., 4, 4) transforms (broadcasting), in float64."""
    if not Ts:
        return np.eye(4)
    out = np.asarray(Ts[0], dtype=np.float64)
    for T in Ts[1:]:
        out = out @ np.asarray(T, dtype=np.float64)
    return out


def quat_normalize(q: npt.ArrayLike) -> F64:
    """Unit quaternions (..., 4) (x, y, z, w); raises ValueError on a zero or non-finite one."""
    quat = np.asarray(q, dtype=np.float64)
    require_finite("quaternion", quat)
    norm = np.linalg.norm(quat, axis=-1, keepdims=True)
    if bool((norm < 1e-12).any()):
        raise DataError("quaternion has zero norm; cannot normalize")
    out: F64 = quat / norm
    return out


def quat_to_rot(q: npt.ArrayLike) -> F64:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) (x, y, z, w), normalized first."""
    x, y, z, w = np.moveaxis(quat_normalize(q), -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def rot_to_quat(R: npt.ArrayLike) -> F64:
    """Quaternions (..., 4) (x, y, z, w) with w >= 0 from rotation matrices (..., 3, 3)."""
    m = np.asarray(R, dtype=np.float64)
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    cands = np.stack(
        [
            np.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 1, 0] - m[..., 0, 1],
                    1 + tr,
                ],
                -1,
            ),
            np.stack(
                [
                    1 + 2 * m[..., 0, 0] - tr,
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 2, 1] - m[..., 1, 2],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 0, 1] + m[..., 1, 0],
                    1 + 2 * m[..., 1, 1] - tr,
                    m[..., 1, 2] + m[..., 2, 1],
                    m[..., 0, 2] - m[..., 2, 0],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 + 2 * m[..., 2, 2] - tr,
                    m[..., 1, 0] - m[..., 0, 1],
                ],
                -1,
            ),
        ],
        axis=-2,
    )  # (..., 4 candidates, 4); pick the numerically largest (Shepperd's method)
    diag = np.stack([1 + tr, cands[..., 1, 0], cands[..., 2, 1], cands[..., 3, 2]], -1)
    best = np.argmax(diag, axis=-1)
    q = np.take_along_axis(cands, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    sign = np.where(q[..., 3:4] < 0, -1.0, 1.0)
    out: F64 = q * sign
    return out


def slerp(q0: npt.ArrayLike, q1: npt.ArrayLike, s: npt.ArrayLike) -> F64:
    """Spherical interpolation (..., 4) from q0 (s=0) to q1 (s=1) along the shorter arc.

    q and -q are the same rotation: when dot(q0, q1) < 0 (antipodal case) q1 is negated so the
    result turns by the smaller angle. Nearly equal rotations use normalized lerp.
    """
    a = quat_normalize(q0)
    b = quat_normalize(q1)
    frac = np.asarray(s, dtype=np.float64)[..., None]
    dot = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(dot < 0, -b, b)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_t = np.sin(theta)
    near = dot > _SLERP_LINEAR_DOT
    safe = np.where(near, 1.0, sin_t)
    w0 = np.where(near, 1.0 - frac, np.sin((1.0 - frac) * theta) / safe)
    w1 = np.where(near, frac, np.sin(frac * theta) / safe)
    out = w0 * a + w1 * b
    res: F64 = out / np.linalg.norm(out, axis=-1, keepdims=True)
    return res


class PoseSamples(NamedTuple):
    """Interpolated poses at query stamps.

    T: (N, 4, 4) float64 poses T_odom_base (identity where not ok).
    ok: (N,) bool, the query lies within the samples and the bracketing gap is within bounds.
    gap_ns: (N,) int64 length of the bracketing sample interval (0 on an exact hit, -1 outside).
    """

    T: F64
    ok: Bool
    gap_ns: I64


def interpolate_poses(
    stamps_ns: npt.ArrayLike,
    positions: npt.ArrayLike,
    quats: npt.ArrayLike,
    query_ns: npt.ArrayLike,
    max_gap_ns: int,
) -> PoseSamples:
    """Poses at `query_ns` (N,) int64 from samples at strictly increasing `stamps_ns` (M,) int64.

    positions (M, 3) metres, quats (M, 4) (x, y, z, w). Linear position, slerp rotation with the
    fraction computed from int64 differences. Queries before the first or after the last sample,
    or inside an interval longer than `max_gap_ns`, are not ok (no extrapolation).
    """
    t = np.asarray(stamps_ns, dtype=np.int64)
    pos = np.asarray(positions, dtype=np.float64)
    q = np.asarray(quats, dtype=np.float64)
    qry = np.asarray(query_ns, dtype=np.int64)
    require_shape("positions", pos, (t.shape[0], 3))
    require_shape("quats", q, (t.shape[0], 4))
    require_finite("positions", pos)
    if t.size > 1 and bool((np.diff(t) <= 0).any()):
        raise DataError("pose stamps must be strictly increasing")
    n = qry.shape[0]
    if t.size == 0:
        return PoseSamples(np.tile(np.eye(4), (n, 1, 1)), np.zeros(n, bool), np.full(n, -1))
    hi = np.clip(np.searchsorted(t, qry, side="left"), 0, t.size - 1)
    exact = t[hi] == qry
    lo = np.clip(hi - 1, 0, t.size - 1)
    inside = (qry >= t[0]) & (qry <= t[-1])
    gap = np.where(exact, 0, t[hi] - t[lo])
    gap = np.where(inside, gap, -1)
    ok = inside & (gap <= max_gap_ns)
    lo = np.where(exact, hi, lo)
    span = np.maximum(t[hi] - t[lo], 1)
    frac = np.where(exact, 0.0, (qry - t[lo]).astype(np.float64) / span.astype(np.float64))
    frac = np.clip(frac, 0.0, 1.0)
    p = pos[lo] + frac[:, None] * (pos[hi] - pos[lo])
    rot = quat_to_rot(slerp(q[lo], q[hi], frac))
    T = make_T(rot, p)
    T[~ok] = np.eye(4)
    return PoseSamples(T, ok, gap.astype(np.int64))


def lidar_to_camera(
    T_base_cam: npt.ArrayLike,
    T_odom_base_image: npt.ArrayLike,
    T_odom_base_sweep: npt.ArrayLike,
    T_base_lidar: npt.ArrayLike,
) -> F64:
    """T_cam_lidar (..., 4, 4) through the odometry frame (SPEC §4, paper §IV-B).

    T_cam_lidar = T_cam_base · T_base_odom(τ) · T_odom_base(τ_P) · T_base_lidar, with the body
    pose at the image stamp τ and at the sweep stamp τ_P; all inputs (..., 4, 4) broadcast.
    """
    return compose(
        invert_T(T_base_cam), invert_T(T_odom_base_image), T_odom_base_sweep, T_base_lidar
    )


def nearest_stamps(query_ns: npt.ArrayLike, stamps_ns: npt.ArrayLike) -> tuple[I64, F64]:
    """Index (N,) of the nearest of sorted `stamps_ns` (M,) per query, and Δτ = τ_P − τ in s.

    Stamps are int64 ns; the signed difference is taken in int64 and only then turned into
    float64 seconds. A tie picks the earlier stamp. M must be at least 1.
    """
    t = np.asarray(stamps_ns, dtype=np.int64)
    q = np.asarray(query_ns, dtype=np.int64)
    if t.size == 0:
        raise DataError("nearest_stamps needs at least one stamp")
    hi = np.clip(np.searchsorted(t, q, side="left"), 0, t.size - 1)
    lo = np.clip(hi - 1, 0, t.size - 1)
    pick_lo = np.abs(q - t[lo]) <= np.abs(t[hi] - q)
    idx = np.where(pick_lo, lo, hi).astype(np.int64)
    dtau = (t[idx] - q).astype(np.float64) / 1e9
    return idx, dtau
