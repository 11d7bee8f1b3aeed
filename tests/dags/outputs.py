"""Compare two run outputs: every cache array and every Parquet table (tests only)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import zarr

IGNORED_COLUMNS = {"seconds"}


def cache_arrays(out: Path) -> dict[str, np.ndarray]:
    """Every array of the cache keyed by its path."""
    root = zarr.open_group(str(out / "cache.zarr"), mode="r")
    found: dict[str, np.ndarray] = {}

    def visit(group: zarr.Group, prefix: str) -> None:
        for name, arr in group.arrays():
            found[f"{prefix}{name}"] = arr[:]
        for name, sub in group.groups():
            visit(sub, f"{prefix}{name}/")

    visit(root, "")
    return found


def tables(out: Path) -> dict[str, list[dict[str, object]]]:
    """Every Parquet file under `out` (relative path -> rows)."""
    found = {}
    for path in sorted(out.rglob("*.parquet")):
        rel = str(path.relative_to(out))
        if rel.startswith("recordings/"):
            continue
        t = pq.read_table(path)
        keep = [c for c in t.column_names if c not in IGNORED_COLUMNS]
        found[rel] = t.select(keep).to_pylist()
    return found


def assert_same_outputs(a: Path, b: Path) -> None:
    """Assert that two output directories hold equal caches and tables."""
    arrays_a, arrays_b = cache_arrays(a), cache_arrays(b)
    assert sorted(arrays_a) == sorted(arrays_b)
    # equal must not mean equally empty: both hold real latents and LiDAR packets
    for suffix in ("/latents_l0", "/g", "/h_cells"):
        assert any(k.endswith(suffix) and np.abs(v.astype(np.float32)).max() > 0
                   for k, v in arrays_a.items()), f"{a}: no non-zero {suffix[1:]} array"
    for key, value in arrays_a.items():
        np.testing.assert_array_equal(value, arrays_b[key], err_msg=key)
    tables_a, tables_b = tables(a), tables(b)
    assert sorted(tables_a) == sorted(tables_b)
    assert any(k.startswith("stats/view_stats") and rows for k, rows in tables_a.items())
    for key, rows in tables_a.items():
        assert rows == tables_b[key], key
