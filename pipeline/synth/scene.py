"""Procedural 3D scenes (corridor, warehouse, forest, plaza) raycast with open3d.

The world frame is the odometry frame `odom`: metres, z up, ground at z = 0. A scene is a list of
`Primitive`s (boxes, cylinders, spheres), each with a surface material, plus the path the robot
walks (`PathSpec`). Obstacles are kept clear of the path. `Raycaster` builds one open3d
`RaycastingScene` and answers one `cast` call per image or sweep.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt
import open3d as o3d

from pipeline.synth.trajectory import PathSpec, path_xy
from schemas.errors import DataError

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

# Surface materials (index into the texture tables in texture.py); -1 means no hit (sky).
MATERIALS = ("ground", "wall", "box", "pillar", "trunk", "canopy", "ceiling", "facade")
MAT = {name: i for i, name in enumerate(MATERIALS)}
CLEARANCE_M = 1.3  # no obstacle footprint closer than this to the walked path


@dataclass(frozen=True)
class Primitive:
    """A solid: kind 'box' (size = full extents x, y, z), 'cylinder' (size = radius, -, height)
    or 'sphere' (size = radius, -, -), centred at `center` (m), rotated by `yaw` (rad) about z."""

    kind: str
    material: str
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float = 0.0


@dataclass(frozen=True)
class Scene:
    """A named scene: primitives and the path the robot walks (all in the odom frame)."""

    name: str
    seed: int
    path: PathSpec
    primitives: list[Primitive] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """Plain JSON-compatible description (scene.json)."""
        return {
            "name": self.name,
            "seed": self.seed,
            "frame": "odom",
            "units": "metres, radians",
            "materials": list(MATERIALS),
            "path": asdict(self.path),
            "primitives": [asdict(p) for p in self.primitives],
        }


def _box(material: str, c: tuple[float, float, float], s: tuple[float, float, float],
         yaw: float = 0.0) -> Primitive:  # fmt: skip
    return Primitive("box", material, tuple(map(float, c)), tuple(map(float, s)), float(yaw))  # type: ignore[arg-type]


def _cyl(material: str, x: float, y: float, r: float, h: float, z0: float = 0.0) -> Primitive:
    return Primitive(
        "cylinder", material, (float(x), float(y), z0 + h / 2), (float(r), 0.0, float(h))
    )


def _clear_of_path(path: PathSpec, xy: F64, radius: F64) -> npt.NDArray[np.bool_]:
    """Which footprints (centre xy (N, 2), radius (N,)) keep CLEARANCE_M from the path."""
    s = np.linspace(-5.0, path.length_m + 5.0, max(64, int(path.length_m * 4)))
    pxy = path_xy(path, s)  # (M, 2)
    d = np.linalg.norm(xy[:, None, :] - pxy[None, :, :], axis=-1).min(axis=1)
    return np.asarray(d - radius > CLEARANCE_M)


def _scatter(rng: np.random.Generator, path: PathSpec, n: int, lo: F64, hi: F64,
             r_lo: float, r_hi: float) -> tuple[F64, F64]:  # fmt: skip
    """Up to n footprints (centres (k, 2), radii (k,)) uniformly in [lo, hi], clear of the path."""
    xy = rng.uniform(lo, hi, size=(n, 2))
    r = rng.uniform(r_lo, r_hi, size=n)
    keep = _clear_of_path(path, xy, r)
    return xy[keep], r[keep]


def _corridor(rng: np.random.Generator, path: PathSpec) -> list[Primitive]:
    L = path.length_m + 20.0
    x0 = -10.0
    half_w, h = 1.6, 3.0
    prims = [
        _box("ground", (x0 + L / 2, 0, -0.05), (L, 2 * half_w + 2, 0.1)),
        _box("ceiling", (x0 + L / 2, 0, h + 0.05), (L, 2 * half_w + 2, 0.1)),
        _box("wall", (x0 + L / 2, half_w + 0.1, h / 2), (L, 0.2, h)),
        _box("wall", (x0 + L / 2, -half_w - 0.1, h / 2), (L, 0.2, h)),
        _box("wall", (x0 - 0.1, 0, h / 2), (0.2, 2 * half_w, h)),
        _box("wall", (x0 + L + 0.1, 0, h / 2), (0.2, 2 * half_w, h)),
    ]
    for x in np.arange(x0 + 2.0, x0 + L - 2.0, 2.5):
        side = 1.0 if rng.random() < 0.5 else -1.0
        d = rng.uniform(0.2, 0.35)
        size = (rng.uniform(0.4, 1.2), 2 * d, rng.uniform(0.4, 1.8))
        prims.append(_box("box", (x + rng.uniform(-0.5, 0.5), side * (half_w - d), size[2] / 2),
                          size))  # fmt: skip
        if rng.random() < 0.3:
            prims.append(_cyl("pillar", x + 1.2, -side * (half_w - 0.15), 0.15, h))
    return prims


def _warehouse(rng: np.random.Generator, path: PathSpec) -> list[Primitive]:
    e, h = 16.0, 6.0
    prims = [_box("ground", (0, 0, -0.05), (2 * e + 2, 2 * e + 2, 0.1))]
    prims += [_box("wall", (sx * e, 0, h / 2), (0.3, 2 * e, h)) for sx in (-1, 1)]
    prims += [_box("wall", (0, sy * e, h / 2), (2 * e, 0.3, h)) for sy in (-1, 1)]
    xy, r = _scatter(rng, path, 90, np.array([-e + 1, -e + 1]), np.array([e - 1, e - 1]), 0.3, 1.0)
    for (x, y), rad in zip(xy, r, strict=True):
        if rng.random() < 0.25:
            prims.append(_cyl("pillar", x, y, 0.25, h))
        else:
            hgt = rng.uniform(0.5, 3.0)
            prims.append(
                _box("box", (x, y, hgt / 2), (1.4 * rad, 1.4 * rad, hgt), rng.uniform(0, np.pi))
            )
    return prims


def _forest(rng: np.random.Generator, path: PathSpec) -> list[Primitive]:
    e = 22.0
    prims = [_box("ground", (0, 0, -0.05), (2 * e + 2, 2 * e + 2, 0.1))]
    xy, r = _scatter(rng, path, 160, np.array([-e, -e]), np.array([e, e]), 0.12, 0.4)
    for (x, y), rad in zip(xy, r, strict=True):
        if rng.random() < 0.2:
            s = rng.uniform(0.3, 0.9)
            prims.append(_box("box", (x, y, s / 3), (s, 0.8 * s, 2 * s / 3), rng.uniform(0, np.pi)))
            continue
        trunk_h = rng.uniform(2.5, 6.0)
        prims.append(_cyl("trunk", x, y, rad, trunk_h))
        cr = rng.uniform(1.2, 2.5)
        prims.append(Primitive("sphere", "canopy", (float(x), float(y), float(trunk_h + 0.6 * cr)),
                               (float(cr), 0.0, 0.0)))  # fmt: skip
    return prims


def _plaza(rng: np.random.Generator, path: PathSpec) -> list[Primitive]:
    e = 24.0
    prims = [_box("ground", (0, 0, -0.05), (2 * e + 20, 2 * e + 20, 0.1)),
             _cyl("pillar", 0.0, 0.0, 2.0, 0.8)]  # fmt: skip
    for k in range(12):  # facades around the square
        a = 2 * np.pi * k / 12
        h = rng.uniform(6.0, 15.0)
        prims.append(_box("facade", (e * np.cos(a), e * np.sin(a), h / 2), (4.0, 13.0, h), a))
    xy, r = _scatter(rng, path, 50, np.array([-e + 4, -e + 4]), np.array([e - 4, e - 4]), 0.2, 0.8)
    for (x, y), rad in zip(xy, r, strict=True):
        if rng.random() < 0.5:
            prims.append(_cyl("pillar", x, y, 0.2, rng.uniform(2.5, 4.5)))
        else:
            prims.append(
                _box("box", (x, y, 0.25), (2.0 * rad + 0.6, 0.5, 0.5), rng.uniform(0, np.pi))
            )
    return prims


BUILDERS = {"corridor": _corridor, "warehouse": _warehouse, "forest": _forest, "plaza": _plaza}
PATHS = {
    "corridor": lambda length: PathSpec("line", length, 0.0, 0.35, 9.0),
    "warehouse": lambda length: PathSpec("loop", length, 8.0, 0.12, 3.0),
    "forest": lambda length: PathSpec("loop", length, 9.0, 0.15, 4.0),
    "plaza": lambda length: PathSpec("loop", length, 9.5, 0.1, 3.0),
}


def build_scene(name: str, seed: int, length_m: float) -> Scene:
    """The scene `name` for a walk of `length_m` metres, deterministic in `seed`."""
    if name not in BUILDERS:
        raise DataError(f"unknown scene {name!r}; known: {sorted(BUILDERS)}")
    rng = np.random.default_rng(np.random.SeedSequence([seed, sum(map(ord, name))]))
    p = PATHS[name](float(length_m))
    path = replace(p, radius=p.radius * rng.uniform(0.92, 1.08), amp=p.amp * rng.uniform(0.7, 1.3))
    return Scene(name, seed, path, BUILDERS[name](rng, path))


def _rot_z(yaw: float) -> F64:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def primitive_mesh(p: Primitive) -> o3d.t.geometry.TriangleMesh:
    """Triangle mesh of one primitive in the world frame."""
    if p.kind == "box":
        mesh = o3d.t.geometry.TriangleMesh.create_box(*p.size)
        verts = mesh.vertex.positions.numpy() - np.asarray(p.size) / 2
    elif p.kind == "cylinder":
        mesh = o3d.t.geometry.TriangleMesh.create_cylinder(p.size[0], p.size[2], 24, 1)
        verts = mesh.vertex.positions.numpy()
    elif p.kind == "sphere":
        mesh = o3d.t.geometry.TriangleMesh.create_sphere(p.size[0], 12)
        verts = mesh.vertex.positions.numpy()
    else:
        raise DataError(f"unknown primitive kind {p.kind!r}")
    verts = verts @ _rot_z(p.yaw).T + np.asarray(p.center)
    mesh.vertex.positions = o3d.core.Tensor.from_numpy(
        np.ascontiguousarray(verts, dtype=np.float32)
    )
    return mesh


@dataclass
class Hits:
    """First hits of N rays: distance `t` (N,) float32 in direction-length units (inf: none),
    `material` (N,) int64 (-1: none), unit-free `normal` (N, 3) float32."""

    t: F32
    material: I64
    normal: F32


class Raycaster:
    """One open3d RaycastingScene over all primitives of a scene."""

    def __init__(self, scene: Scene) -> None:
        """Add every primitive as its own geometry and remember its material."""
        self._rs = o3d.t.geometry.RaycastingScene()
        mats: list[int] = []
        for p in scene.primitives:
            gid = self._rs.add_triangles(primitive_mesh(p))
            assert gid == len(mats)
            mats.append(MAT[p.material])
        self._mat = np.asarray([*mats, -1], dtype=np.int64)

    def cast_soa(self, origin: F32, dirs: F32) -> Hits:
        """Cast rays from one origin (3,) along dirs (3, N) float32 (unit length) in one call."""
        rays = np.empty((dirs.shape[1], 6), dtype=np.float32)
        rays[:, :3] = origin
        rays[:, 3:] = dirs.T
        return self._cast(rays)

    def cast(self, origins: F32, dirs: F32) -> Hits:
        """Cast rays (origins, dirs: (N, 3) float32; dirs unit length) in one call."""
        rays = np.ascontiguousarray(np.concatenate([origins, dirs], axis=1), dtype=np.float32)
        return self._cast(rays)

    def _cast(self, rays: F32) -> Hits:
        """One cast_rays call over rays (N, 6) float32."""
        out = self._rs.cast_rays(o3d.core.Tensor.from_numpy(rays))
        t = out["t_hit"].numpy()
        gid = out["geometry_ids"].numpy().astype(np.int64)
        gid = np.where(np.isfinite(t), gid, len(self._mat) - 1)
        return Hits(t, self._mat[gid], out["primitive_normals"].numpy())
