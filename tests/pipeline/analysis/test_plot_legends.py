"""The accuracy map explains its marks: a legend for border cells and blank cells."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pyarrow as pa
import pytest

from pipeline.analysis import plots


def test_accuracy_map_has_a_legend(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[Any] = []
    real = plots._save

    def keep(fig: Any, out: Path | str) -> Path:
        seen.append(fig)
        return real(fig, out)

    monkeypatch.setattr(plots, "_save", keep)
    cells = pa.table({"row": [0, 0, 1], "col": [0, 1, 1], "abs_rel": [0.1, 0.5, None],
                      "border": [True, False, False]})
    assert plots.plot_error_map(cells, tmp_path / "map.png", "t").stat().st_size > 0
    legend = seen[0].axes[0].get_legend()
    assert legend is not None
    assert [t.get_text() for t in legend.get_texts()] == ["border cell",
                                                          "no packet or no reference"]
