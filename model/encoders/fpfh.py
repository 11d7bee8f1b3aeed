"""Embedded point encoder `fpfh`: hand-made local geometry lifted to C_u channels.

Not a learned encoder: it needs no weights and stands in for Utonia so that packets carry
honest per-point descriptors. Per point it computes (all from the point's neighbourhood and
its own coordinates, never from sweep-wide statistics, so a point's feature does not change
with the rest of the sweep):

- open3d normals (KDTreeSearchParamHybrid), oriented towards the sensor at the origin (3);
- FPFH at each radius in `radii` (33 each): every 11-bin sub-histogram is divided by its sum
  and centred, (p - 1/11) * sqrt(11);
- eigenvalue features of the k-nearest-neighbour covariance, l1 >= l2 >= l3: linearity
  (l1-l2)/l1, planarity (l2-l3)/l1, scattering l3/l1, each as (x - 1/3) * 3 (3);
- height z / 2 m, log range log(1+r) - log(11), neighbour spacing log(mean kNN distance /
  0.1 m), intensity log(1+i) / log(256) * 2 - 1 (0 when absent) (4).

These D = 10 + 33 * len(radii) values are clipped to [-5, 5] and lifted by a fixed seeded
random projection W (D, C_u) ~ N(0, 1/D), bias b ~ U(-0.5, 0.5), then tanh: features are in
(-1, 1), deterministic for a seed, and every channel is a distinct nonlinear mixture.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from model.encoders.base import PointEncoder
from schemas.errors import DataError

N_FPFH = 33
N_GEOM = 10
CHUNK_ROWS = 16384


@dataclass(frozen=True)
class FPFHParams:
    """Neighbourhood sizes: FPFH radii (m) with neighbour caps, normals, eigen-feature k."""

    radii: tuple[float, ...] = (0.25, 0.5, 1.0)
    max_nn: tuple[int, ...] = (16, 32, 64)
    normal_radius: float = 0.5
    normal_nn: int = 30
    k_eigen: int = 16

    def __post_init__(self) -> None:
        if len(self.radii) != len(self.max_nn) or not self.radii:
            raise DataError(f"fpfh: radii {self.radii} and max_nn {self.max_nn} must pair up")


def estimate_normals(xyz: np.ndarray, radius: float, max_nn: int) -> o3d.geometry.PointCloud:
    """open3d point cloud of float (N, 3) metres with unit normals facing the origin."""
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz.astype(np.float64)))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=max_nn))
    pcd.orient_normals_towards_camera_location(np.zeros(3))
    return pcd


def fpfh_multiscale(pcd: o3d.geometry.PointCloud, radii: tuple[float, ...],
                    max_nn: tuple[int, ...]) -> np.ndarray:
    """Normalized FPFH, float64 (N, 33 * len(radii)); empty neighbourhoods give zeros."""
    blocks = []
    for r, nn in zip(radii, max_nn, strict=True):
        f = o3d.pipelines.registration.compute_fpfh_feature(  # type: ignore[call-arg]
            pcd, o3d.geometry.KDTreeSearchParamHybrid(radius=r, max_nn=nn))
        h = np.asarray(f.data).T.reshape(-1, 3, 11)             # (N, 3, 11)
        s = h.sum(axis=2, keepdims=True)
        p = np.divide(h, s, out=np.full_like(h, 1.0 / 11), where=s > 0)
        blocks.append(((p - 1.0 / 11) * np.sqrt(11.0)).reshape(-1, N_FPFH))
    return np.concatenate(blocks, axis=1)


def eigen_features(xyz: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Linearity, planarity, scattering (N, 3) in [0, 1] and mean kNN distance (N,) metres.

    Neighbourhoods are the k nearest points (the point itself included), k capped at N.
    Degenerate neighbourhoods (all points equal) give zeros.
    """
    n = xyz.shape[0]
    k = min(k, n)
    dist, idx = cKDTree(xyz).query(xyz, k=list(range(1, k + 1)))  # (N, k)
    nb = xyz[idx] - xyz[idx].mean(axis=1, keepdims=True)           # (N, k, 3)
    cov = np.einsum("nki,nkj->nij", nb, nb) / k                    # (N, 3, 3)
    lam = np.clip(np.linalg.eigvalsh(cov)[:, ::-1], 0.0, None)     # (N, 3) descending
    l1 = lam[:, 0:1]
    ratios = np.divide(np.stack([lam[:, 0] - lam[:, 1], lam[:, 1] - lam[:, 2], lam[:, 2]], 1),
                       l1, out=np.zeros((n, 3)), where=l1 > 1e-12)
    spacing = dist[:, 1:].mean(axis=1) if k > 1 else np.zeros(n)
    return ratios, spacing


def point_descriptors(xyz: np.ndarray, intensity: np.ndarray | None,
                      params: FPFHParams) -> np.ndarray:
    """Fixed-scale local descriptors float64 (N, 10 + 33 * len(radii)), clipped to [-5, 5].

    xyz: (N >= 1, 3) metres in the LiDAR frame; intensity: (N,) or None.
    """
    x = xyz.astype(np.float64)
    pcd = estimate_normals(x, params.normal_radius, params.normal_nn)
    normals = np.asarray(pcd.normals)                                # (N, 3)
    hist = fpfh_multiscale(pcd, params.radii, params.max_nn)                       # (N, 33R)
    ratios, spacing = eigen_features(x, params.k_eigen)
    rng = np.linalg.norm(x, axis=1)
    inten = (np.zeros(len(x)) if intensity is None
             else np.log1p(np.clip(intensity, 0, None)) / np.log(256.0) * 2 - 1)
    geom = np.column_stack([
        normals,
        (ratios - 1.0 / 3) * 3,
        x[:, 2] / 2.0,
        np.log1p(rng) - np.log(11.0),
        np.log(np.maximum(spacing, 1e-3) / 0.1),
        inten,
    ])                                                               # (N, 10)
    feat: np.ndarray = np.clip(np.concatenate([geom, hist], axis=1), -5.0, 5.0)
    return feat


def random_lift(dim_in: int, dim_out: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded projection W float32 (dim_in, dim_out) ~ N(0, 1/dim_in) and bias (dim_out,)."""
    rng = np.random.default_rng(seed)
    w = rng.standard_normal((dim_in, dim_out)) / np.sqrt(dim_in)
    b = rng.uniform(-0.5, 0.5, dim_out)
    return w.astype(np.float32), b.astype(np.float32)


class FPFHEncoder(PointEncoder):
    """Normals + multi-scale FPFH + local geometry, lifted to C_u channels (module doc)."""

    name = "fpfh"
    version = "1"
    pretrained = False

    def __init__(self, channels: int = 1224, seed: int = 0,
                 params: FPFHParams | None = None) -> None:
        super().__init__()
        self.out_channels = int(channels)
        self.seed = int(seed)
        self.params = params or FPFHParams()
        self.in_dim = N_GEOM + N_FPFH * len(self.params.radii)
        self.w, self.b = random_lift(self.in_dim, self.out_channels, self.seed)
        key = f"fpfh v{self.version} seed={self.seed} C={self.out_channels} {asdict(self.params)}"
        self.weights_hash = hashlib.sha256(key.encode()).hexdigest()[:16]

    def _encode_sweep(self, xyz: np.ndarray, intensity: np.ndarray | None) -> np.ndarray:
        out = np.empty((xyz.shape[0], self.out_channels), np.float32)
        if xyz.shape[0] == 0:
            return out
        d = point_descriptors(xyz, intensity, self.params).astype(np.float32)  # (N, D)
        for s in range(0, len(d), CHUNK_ROWS):
            block = out[s:s + CHUNK_ROWS]
            np.matmul(d[s:s + CHUNK_ROWS], self.w, out=block)
            block += self.b
            np.tanh(block, out=block)
        return out
