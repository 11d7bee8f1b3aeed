"""The sweep's angular resolution: the density bound needs no rings told apart."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from packets.scan_resolution import (
    density_step_deg,
    directions_deg,
    scan_resolution_deg,
    solid_angle_deg2,
)


def ring_scan(rings: int, cols: int, el_lo: float = -16.0, el_hi: float = 15.0,
              jitter_deg: float = 0.0, seed: int = 0, range_m: float = 10.0) -> np.ndarray:
    """A spinning scanner's sweep (rings * cols, 3) m: `cols` azimuth columns over 360 deg
    of `rings` rings between el_lo and el_hi deg, each direction jittered by `jitter_deg`."""
    rng = np.random.default_rng(seed)
    az = np.radians(np.linspace(-180.0, 180.0, cols, endpoint=False))
    el = np.radians(np.linspace(el_lo, el_hi, rings))
    a, e = (g.ravel() for g in np.meshgrid(az, el, indexing="ij"))
    a = a + np.radians(rng.uniform(-jitter_deg, jitter_deg, a.shape))
    e = e + np.radians(rng.uniform(-jitter_deg, jitter_deg, e.shape))
    return range_m * np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], 1)


@settings(max_examples=60, deadline=None)
@given(rings=st.integers(4, 64), cols=st.integers(36, 2048))
def test_the_density_bound_lies_between_the_two_steps(rings: int, cols: int) -> None:
    az_step, el_step = 360.0 / cols, 31.0 / (rings - 1)
    step = density_step_deg(ring_scan(rings, cols))
    # never coarser than the coarser step (a fine scan keeps its power to fail), about the
    # geometric mean of the two (the first and last ring bound the span: (rings-1)/rings)
    assert np.sqrt(az_step * el_step) * 0.8 <= step <= max(az_step, el_step) * 1.1


def test_a_sweep_of_coarse_columns_is_coarse_whatever_its_rings() -> None:
    """32 rings x 32 columns (11.25 deg) with rings ~1 deg apart: the ring-neighbour step can
    read ~0 there; the resolution must not."""
    xyz = ring_scan(32, 32, jitter_deg=0.4)
    assert scan_resolution_deg(0.0077, xyz) > 1.5
    assert scan_resolution_deg(0.0077, xyz) > 3.0


def test_a_dense_sweep_stays_fine() -> None:
    """A 32 x 512 sweep (0.7 deg columns, 1 deg rings) and a GrandTour-like 32 x 2000 one."""
    assert scan_resolution_deg(0.70, ring_scan(32, 512)) < 1.5
    assert scan_resolution_deg(0.18, ring_scan(32, 2000)) < 0.5


def test_the_ring_step_wins_when_coarser() -> None:
    xyz = ring_scan(32, 2000)
    assert scan_resolution_deg(2.0, xyz) == 2.0


def test_a_sector_scanner_counts_only_its_sector() -> None:
    """A forward-looking scanner (a Livox-like 70 deg sector) is as dense as its points over
    its own sector, not over 360 deg."""
    full = ring_scan(32, 512)
    dirs = directions_deg(full)
    sector = full[np.abs(dirs[:, 0]) < 35.0]
    assert density_step_deg(sector) < 1.5
    area = solid_angle_deg2(directions_deg(sector))
    assert 60.0 * 30.0 <= area <= 80.0 * 32.0


def test_too_few_or_no_finite_points_is_unknown() -> None:
    assert density_step_deg(np.zeros((3, 3))) == 0.0
    assert density_step_deg(np.full((10, 3), np.nan)) == 0.0
    assert scan_resolution_deg(1.2, np.zeros((0, 3))) == 1.2
