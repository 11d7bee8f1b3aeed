"""The cache benchmark's write half: same state for both formats, medians and spread."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.cache_write import WriteRuns, alternating_writes


def test_figures_are_median_ratios_with_paired_spread() -> None:
    runs = WriteRuns({"npy": [1.0, 2.0, 3.0], "store": [0.5, 4.0, 1.5]},
                     {"npy": [1.0, 1.0, 1.0], "store": [2.0, 0.5, 1.0]})
    out = runs.figures()
    assert out["write_vs_npy_per_view"] == pytest.approx(2.0 / 1.5)
    assert out["write_vs_npy_paired_min"] == pytest.approx(0.5)
    assert out["write_vs_npy_paired_max"] == pytest.approx(2.0)
    assert out["write_cpu_vs_npy_per_view"] == pytest.approx(1.0)
    assert out["write_cpu_vs_npy_paired_max"] == pytest.approx(2.0)
    assert out["write_rounds"] == 3


def test_each_write_starts_with_no_other_tree(tmp_path: Path) -> None:
    seen: list[tuple[str, list[str]]] = []

    def writer(name: str):  # type: ignore[no-untyped-def]
        def write(root: Path) -> float:
            seen.append((name, sorted(p.name for p in tmp_path.iterdir())))
            root.mkdir()
            (root / "x").write_bytes(b"1")
            return 1.0
        return write

    runs = alternating_writes(tmp_path, {"a": writer("a"), "b": writer("b")}, 3)
    assert [n for n, _ in seen] == ["a", "b",  # one untimed write each first
                                    "a", "b", "b", "a", "a", "b"]  # order alternates
    assert all(others == [] for _, others in seen)  # no tree of an earlier write remains
    assert list(tmp_path.iterdir()) == []
    assert runs.wall == {"a": [1.0] * 3, "b": [1.0] * 3}
