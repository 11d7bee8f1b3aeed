"""packets.null_stats.z_score: its value and its sign at a null without spread."""

from __future__ import annotations

import math

from packets.null_stats import z_score


def test_z_score_is_the_distance_in_standard_deviations() -> None:
    assert z_score(0.5, 0.1, 0.2) == (0.5 - 0.1) / 0.2
    assert z_score(0.0, 0.1, 0.05) < 0


def test_a_null_without_spread_gives_the_sign_only() -> None:
    assert z_score(0.2, 0.1, 0.0) == math.inf
    assert z_score(0.0, 0.1, 0.0) == -math.inf
    assert z_score(0.1, 0.1, 0.0) == 0.0
