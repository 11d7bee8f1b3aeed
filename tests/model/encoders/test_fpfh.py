"""The embedded `fpfh` point encoder: contract suite plus known geometric answers."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from model.encoders.fpfh import (
    FPFHEncoder,
    FPFHParams,
    eigen_features,
    estimate_normals,
    fpfh_multiscale,
    point_descriptors,
)
from tests.model.encoders.contract import PointEncoderContract

SMALL = FPFHParams(radii=(0.25, 0.5), max_nn=(24, 48))


def scene(n: int = 1500, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Sensor-frame scene from open3d primitives: a box (wall) and a sphere over a ground
    plane 1.5 m below the sensor; xyz (n, 3) float32 metres and intensity (n,) float32."""
    o3d.utility.random.seed(seed)
    box = o3d.geometry.TriangleMesh.create_box(0.4, 4.0, 2.0).translate((5.0, -2.0, -1.5))
    ball = o3d.geometry.TriangleMesh.create_sphere(0.6).translate((3.0, 2.0, -0.9))
    parts = [np.asarray(m.sample_points_uniformly(n // 3).points) for m in (box, ball)]
    rng = np.random.default_rng(seed)
    ground = np.column_stack([rng.uniform(1, 8, n - 2 * (n // 3)), rng.uniform(-4, 4, n - 2 *
                              (n // 3)), np.full(n - 2 * (n // 3), -1.5)])
    xyz = np.concatenate([*parts, ground]).astype(np.float32)
    return xyz, rng.uniform(0, 255, len(xyz)).astype(np.float32)


class TestFPFHEncoder(PointEncoderContract):
    def make(self, seed: int) -> FPFHEncoder:
        return FPFHEncoder(channels=1224, seed=seed)

    def sweep(self) -> tuple[np.ndarray, np.ndarray | None]:
        return scene()


class TestFPFHEncoderNoIntensityNarrow(PointEncoderContract):
    def make(self, seed: int) -> FPFHEncoder:
        return FPFHEncoder(channels=64, seed=seed, params=SMALL)

    def sweep(self) -> tuple[np.ndarray, np.ndarray | None]:
        return scene(600, seed=1)[0], None


def plane(n: int = 400, z: float = -1.5, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(2, 6, n), rng.uniform(-2, 2, n), np.full(n, z)])


def test_ground_normals_face_the_sensor() -> None:
    normals = np.asarray(estimate_normals(plane(), 0.5, 30).normals)
    np.testing.assert_allclose(normals, np.tile([0.0, 0.0, 1.0], (len(normals), 1)),
                               atol=1e-6)


def test_eigen_features_of_a_plane_and_a_line() -> None:
    flat, _ = eigen_features(plane(), k=16)
    assert np.all(flat[:, 2] < 1e-9)                 # scattering 0 on a plane
    assert np.median(flat[:, 1]) > 0.3               # planar
    t = np.linspace(0, 3, 200)
    line, spacing = eigen_features(np.column_stack([t, 2 * t, -t]), k=8)
    np.testing.assert_allclose(line[:, 0], 1.0, atol=1e-9)  # linearity 1 on a line
    step = 3 * np.sqrt(6) / 199
    assert np.all(spacing > step) and np.all(spacing < 8 * step)


def test_eigen_features_degenerate_neighbourhood_is_zero() -> None:
    ratios, spacing = eigen_features(np.zeros((5, 3)), k=16)
    assert np.array_equal(ratios, np.zeros((5, 3))) and np.array_equal(spacing, np.zeros(5))


def test_fpfh_blocks_are_centred_distributions() -> None:
    xyz, _ = scene(600)
    pcd = estimate_normals(xyz.astype(np.float64), 0.5, 30)
    f = fpfh_multiscale(pcd, (0.5,), (48,)).reshape(-1, 3, 11)
    p = f / np.sqrt(11) + 1 / 11
    np.testing.assert_allclose(p.sum(axis=2), 1.0, atol=1e-9)
    assert (p >= -1e-12).all()


def test_a_point_feature_ignores_far_away_points() -> None:
    """Descriptors are local: adding points beyond every radius changes nothing."""
    xyz, inten = scene(600)
    far = xyz[:200] + np.float32([0.0, 0.0, 50.0])
    both = np.concatenate([xyz, far])
    alone = point_descriptors(xyz, inten, SMALL)
    joint = point_descriptors(both, np.concatenate([inten, inten[:200]]), SMALL)
    np.testing.assert_allclose(joint[: len(xyz)], alone, atol=1e-9)


def test_intensity_and_seed_change_features() -> None:
    xyz, inten = scene(300)
    enc = FPFHEncoder(channels=32, seed=0, params=SMALL)
    with_i, without = enc.encode(xyz, inten), enc.encode(xyz, None)
    assert not np.allclose(with_i, without)
    other = FPFHEncoder(channels=32, seed=1, params=SMALL)
    assert not np.allclose(other.encode(xyz, None), without)
    assert other.weights_hash != enc.weights_hash


def test_radii_must_pair_with_max_nn() -> None:
    with pytest.raises(ValueError, match="pair"):
        FPFHParams(radii=(0.5, 1.0), max_nn=(30,))
