"""The paper-size update bench: its batch and its linear extension (the timing runs for
minutes and is not run here)."""

from __future__ import annotations

import pytest

from bench.paper_step import PAPER, _line, paper_batch
from model.adapter import build_packet


def test_paper_batch_has_the_paper_sizes_and_consistent_packets() -> None:
    b = paper_batch(2)
    assert b["latents"].shape == (2, 4, 1536, 16, 24)
    assert b["h"].shape[0] == int((b["g"][:, :, 0] > 0.5).sum()) and b["h"].shape[1] == 1224
    ell = build_packet("full", b["g"], b["h"], PAPER["c_u"], b["latents"])
    assert ell is not None and ell.shape == (2, 4, 16, 24, 6 + 1224)


def test_line_extends_exactly_and_reports_the_residual() -> None:
    assert _line([1.0, 2.0, 3.0], [5.0, 7.0, 9.0], 28.0) == (pytest.approx(59.0), 0.0)
    value, resid = _line([1.0, 2.0, 3.0], [1.0, 3.0, 2.0], 3.0)
    assert value == pytest.approx(2.5) and resid == pytest.approx(1.0)
