"""The HF proof's view rows: rows whose stamp chunk could not be read (stamp 0, not ok) are
never a view's row, and the views spread over the readable stamps."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any, cast

import numpy as np

from pipeline.inspect.prove_hf import _row_at, usable


def _store(ns: list[int], ok: list[bool]) -> Any:
    return cast(Any, SimpleNamespace(stamps=lambda _: (np.asarray(ns, np.int64),
                                                      np.asarray(ok, bool))))


def test_unreadable_stamps_are_never_a_views_row() -> None:
    # rows 0-1 and 4 sit in unreadable chunks (read as 0): searched over every row, 0 breaks
    # the order and the first view would land on row 0
    rows = usable(_store([0, 0, 200, 300, 0, 500], [False, False, True, True, False, True]), "g")
    assert rows.rows.tolist() == [2, 3, 5] and rows.stamps.tolist() == [200, 300, 500]
    assert _row_at(rows, 150) == (2, 200)
    assert _row_at(rows, 300) == (3, 300)  # at or after: a stamp equal to the time is taken
    assert _row_at(rows, 301) == (5, 500)
    assert _row_at(rows, 501) is None


def test_equal_stamps_keep_their_row_order() -> None:
    rows = usable(_store([300, 100, 100, 200], [True] * 4), "g")
    assert rows.rows.tolist() == [1, 2, 3, 0]
    assert _row_at(rows, 100) == (1, 100)
