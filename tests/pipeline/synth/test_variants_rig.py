"""Rig variants as transforms of a written mission: split bags cut in time without moving a
message across parts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Reader, Writer

from pipeline.synth.variants_rig import ros1_typestore, split_bags

T0 = 1_716_999_999_689_071_096
"""A ns epoch that float64 rounds up (to a multiple of 256 ns): the first edge of a split
computed in float64 lies after it."""


def _bag(path: Path, stamps: list[int]) -> None:
    ts = ros1_typestore()
    m = ts.types
    with Writer(path) as w:
        conn = w.add_connection("/n", "std_msgs/msg/Int64", typestore=ts)
        for i, t in enumerate(stamps):
            w.write(conn, t, ts.serialize_ros1(m["std_msgs/msg/Int64"](data=i),
                                               "std_msgs/msg/Int64"))  # fmt: skip


def _stamps(path: Path) -> list[int]:
    with Reader(path) as r:
        return [t for _, t, _ in r.messages()]


def test_split_keeps_the_first_message_in_the_first_part(tmp_path: Path) -> None:
    assert int(np.float64(T0)) > T0  # the rounding the split must not depend on
    stamps = [T0 + k * 100_000_000 for k in range(7)] + [T0 + 700_000_000]  # the end: a tie
    _bag(tmp_path / "m_x.bag", stamps)
    split_bags(tmp_path, parts=2)
    first, second = _stamps(tmp_path / "m_x_0.bag"), _stamps(tmp_path / "m_x_1.bag")
    assert not (tmp_path / "m_x.bag").exists()
    assert first + second == stamps  # every message once, parts in time order
    # equal spans of [T0, T_end + 1): the edge is T0 + 350_000_000 (inclusive on the right)
    assert first == stamps[:4] and second == stamps[4:]


def test_split_in_three_at_exact_edges(tmp_path: Path) -> None:
    stamps = [T0, T0 + 2, T0 + 3, T0 + 5]  # span 6 ns: edges T0, T0 + 2, T0 + 4, T0 + 6
    _bag(tmp_path / "m_y.bag", stamps)
    split_bags(tmp_path, parts=3)
    parts = [_stamps(tmp_path / f"m_y_{i}.bag") for i in range(3)]
    assert parts == [[T0], [T0 + 2, T0 + 3], [T0 + 5]]
