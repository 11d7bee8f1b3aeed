"""PointCloud2 decoding from msg.fields: unaligned float64, big-endian, row padding, drops."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.ingest.sources.pointcloud import FieldSpan as SPAN
from pipeline.ingest.sources.pointcloud import (
    cloud_dtype,
    cloud_summary,
    decode_cloud,
    layout_problem,
    point_kinds,
)
from schemas.errors import DataError
from schemas.time_conventions import DRIVERS, TimeConvention
from tests.pipeline.ingest.bagkit import HESAI_DTYPE, mark_invalid, sweep_points

HEADER_NS = 1_700_000_000_123_456_789
HESAI = DRIVERS["hesai (GrandTour)"]


def _msg(arr: np.ndarray, fields: list[tuple[str, int, int]], big: bool = False,
         height: int = 1, pad: int = 0) -> SimpleNamespace:  # fmt: skip
    step = arr.dtype.itemsize
    width = arr.size // height
    rows = arr.tobytes()
    if pad:
        rows = b"".join(rows[i * width * step:(i + 1) * width * step] + b"\0" * pad
                        for i in range(height))  # fmt: skip
    fs = [SimpleNamespace(name=n, offset=o, datatype=d, count=1) for n, o, d in fields]
    return SimpleNamespace(fields=fs, is_bigendian=big, point_step=step, width=width,
                           height=height, row_step=width * step + pad,
                           data=np.frombuffer(rows, np.uint8))  # fmt: skip


HESAI_FIELDS = [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 7), ("ring", 16, 4),
                ("timestamp", 18, 8)]  # fmt: skip


def test_hesai_layout_unaligned_float64_and_drops() -> None:
    pts = sweep_points(3, 50, nan_points=4)
    pts["timestamp"] = HEADER_NS / 1e9 + np.linspace(0, 0.09, 50)
    sweep = decode_cloud(_msg(pts, HESAI_FIELDS), HEADER_NS, HESAI)
    assert cloud_dtype(_msg(pts, HESAI_FIELDS)).itemsize == 26
    assert sweep.counts.total == 50 and sweep.counts.nonfinite == 4 and sweep.counts.zero == 4
    assert sweep.counts.valid == 42 == sweep.xyz.shape[0]
    keep = slice(8, None)
    np.testing.assert_array_equal(sweep.xyz[:, 0], pts["x"][keep])
    np.testing.assert_array_equal(sweep.intensity, pts["intensity"][keep])
    # float64 absolute seconds -> int64 ns, within the float64 resolution at 1.7e9 s
    expect = HEADER_NS + np.rint(np.linspace(0, 0.09, 50)[keep] * 1e9)
    assert np.abs(sweep.t_ns - expect).max() < 1_000
    assert sweep.t_ns.dtype == np.int64 and sweep.xyz.dtype == np.float32


def test_big_endian_row_padding_and_relative_time() -> None:
    dt = np.dtype({"names": ["t", "x", "y", "z"], "formats": [">u4", ">f4", ">f4", ">f4"],
                   "offsets": [0, 4, 8, 12], "itemsize": 20})  # fmt: skip
    arr = np.zeros(6, dtype=dt)
    arr["x"], arr["y"], arr["z"] = np.arange(1, 7), 2.0, -1.0
    arr["t"] = np.arange(6) * 1000
    msg = _msg(arr, [("t", 0, 6), ("x", 4, 7), ("y", 8, 7), ("z", 12, 7)], big=True,
               height=2, pad=8)  # fmt: skip
    sweep = decode_cloud(msg, HEADER_NS, TimeConvention("t", "uint32", "ns", "first_point"))
    np.testing.assert_array_equal(sweep.xyz[:, 0], np.arange(1, 7, dtype=np.float32))
    np.testing.assert_array_equal(sweep.t_ns, HEADER_NS + np.arange(6) * 1000)
    # without a convention every point takes the header stamp
    np.testing.assert_array_equal(decode_cloud(msg, HEADER_NS).t_ns, np.full(6, HEADER_NS))
    np.testing.assert_array_equal(sweep.intensity, np.zeros(6, np.float32))


def test_missing_xyz_and_short_data_are_named() -> None:
    arr = np.zeros(3, dtype=HESAI_DTYPE)
    with pytest.raises(ValueError, match="lacks field"):
        decode_cloud(_msg(arr, [("x", 0, 7), ("y", 4, 7)]), HEADER_NS)
    msg = _msg(arr, HESAI_FIELDS)
    msg.data = msg.data[:-5]
    with pytest.raises(ValueError, match="bytes"):
        decode_cloud(msg, HEADER_NS)


def test_empty_cloud_has_zero_counts() -> None:
    sweep = decode_cloud(_msg(np.zeros(0, HESAI_DTYPE), HESAI_FIELDS), HEADER_NS)
    assert sweep.counts.total == 0 and sweep.xyz.shape == (0, 3)


def test_summary_matches_full_decode() -> None:
    pts = sweep_points(5, 80, nan_points=6)
    pts["timestamp"] = HEADER_NS / 1e9 + np.linspace(0, 0.09, 80)
    msg = _msg(pts, HESAI_FIELDS)
    full = decode_cloud(msg, HEADER_NS, HESAI)
    counts, t_first, t_last = cloud_summary(msg, HEADER_NS, HESAI)
    assert counts == full.counts
    assert (t_first, t_last) == (int(full.t_ns.min()), int(full.t_ns.max()))


def test_huge_coordinates_are_corrupt_and_bad_point_times_take_the_header_stamp() -> None:
    pts = sweep_points(7, 60, nan_points=0)
    pts["timestamp"] = HEADER_NS / 1e9 + np.linspace(0, 0.09, 60)
    pts["x"][10:15] = 3e38  # finite, but would overflow depth statistics
    pts["z"][15] = -2e5
    pts["timestamp"][20] = np.inf
    pts["timestamp"][21] = np.nan
    pts["timestamp"][22] = 1e19  # finite, but beyond int64 nanoseconds
    msg = _msg(pts, HESAI_FIELDS)
    with np.errstate(all="raise"):  # no overflow or invalid cast on the way
        sweep = decode_cloud(msg, HEADER_NS, HESAI)
    # coordinates decide corruption (PCL/REP 117); a time value never does
    assert sweep.counts.corrupt == 6 and sweep.counts.nonfinite == 0
    assert sweep.counts.valid == 60 - 6 - sweep.counts.zero
    assert np.abs(sweep.xyz).max() <= 1e5
    assert sweep.t_ns.min() >= HEADER_NS - 1_000 and sweep.t_ns.max() <= HEADER_NS + 90_001_000
    kept = np.flatnonzero(point_kinds(pts["x"], pts["y"], pts["z"]).keep)
    at = {int(i): t for i, t in zip(kept, sweep.t_ns, strict=True)}
    assert at[20] == at[21] == at[22] == HEADER_NS  # unreadable times: the header stamp
    assert cloud_summary(msg, HEADER_NS, HESAI)[0] == sweep.counts


@pytest.mark.parametrize(("style", "kind"), [("nan", "nan"), ("x_nan", "nan"),
                                             ("posinf", "posinf"), ("neginf", "neginf"),
                                             ("zero", "zero")])  # fmt: skip
def test_each_missing_return_convention_is_dropped_and_counted_by_kind(style: str,
                                                                       kind: str) -> None:
    pts = sweep_points(2, 40)
    pts["timestamp"] = HEADER_NS / 1e9 + np.linspace(0, 0.09, 40)
    mark_invalid(pts[:6], style)
    sweep = decode_cloud(_msg(pts, HESAI_FIELDS), HEADER_NS, HESAI)
    c = sweep.counts
    assert getattr(c, kind) == 6 and c.corrupt == 0 and c.valid == 34 == sweep.xyz.shape[0]
    assert c.nonfinite == (0 if kind == "zero" else 6)
    assert np.isfinite(sweep.xyz).all()


def test_a_point_counts_once_nan_before_posinf_before_neginf() -> None:
    x = np.array([np.nan, np.inf, -np.inf, np.inf, 1.0, 0.0, 2e5], np.float32)
    y = np.array([np.inf, -np.inf, 0.0, np.nan, 1.0, 0.0, 0.0], np.float32)
    z = np.zeros(7, np.float32)
    c = point_kinds(x, y, z).counts()
    assert (c.nan, c.posinf, c.neginf, c.zero, c.corrupt, c.valid) == (2, 1, 1, 1, 1, 1)


FLOATS = st.sampled_from([np.nan, np.inf, -np.inf, 0.0, 1.5, -3.0, 1e5, 1.0000001e5, 3e38])


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(FLOATS, FLOATS, FLOATS), min_size=0, max_size=30))
def test_point_kinds_are_disjoint_and_cover_every_point(xyz: list[tuple[float, ...]]) -> None:
    a = np.array(xyz, dtype=np.float64).reshape(-1, 3)
    k = point_kinds(a[:, 0], a[:, 1], a[:, 2])
    masks = np.stack([k.nan, k.posinf, k.neginf, k.corrupt, k.zero, k.keep])
    assert (masks.sum(axis=0) == 1).all()
    kept = a[k.keep]
    assert np.isfinite(kept).all() and (np.abs(kept) <= 1e5).all()
    assert not (kept == 0).all(axis=1).any()




def test_layout_problem_names_overlap_out_of_bounds_and_duplicates() -> None:
    xyz = [SPAN("x", 7, 0, 1), SPAN("y", 7, 4, 1), SPAN("z", 7, 8, 1)]
    assert layout_problem(xyz, 12) is None  # the last field ends exactly at point_step: fine
    assert "past point_step 11" in str(layout_problem(xyz, 11))
    assert "overlap" in str(layout_problem([SPAN("x", 7, 0, 1), SPAN("y", 7, 0, 1),
                                            SPAN("z", 7, 8, 1)], 12))
    assert "overlap" in str(layout_problem([*xyz, SPAN("time", 8, 10, 1)], 18))  # 10..17 vs z
    assert "more than once" in str(layout_problem([*xyz, SPAN("x", 7, 12, 1)], 16))
    assert "past point_step" in str(layout_problem([*xyz, SPAN("rgb", 7, 12, 10**6)], 16))
    assert "unknown PointField datatype 42" in str(layout_problem([*xyz, SPAN("q", 42, 12, 1)],
                                                                     16))
    # adjacent (touching) fields do not overlap; count 0 reads as one element, as in PCL
    assert layout_problem([*xyz, SPAN("intensity", 7, 12, 0)], 16) is None
    # two fields the reader never reads may share bytes (a union some drivers write)
    assert layout_problem([*xyz, SPAN("rgb", 7, 12, 1), SPAN("rgba", 6, 12, 1)], 16) is None


@pytest.mark.parametrize("offsets", [{"y": 0}, {"z": 24}, {"timestamp": 19}])
def test_a_contradicting_layout_is_a_data_error_never_a_numpy_error(offsets: dict) -> None:
    pts = sweep_points(3, 20)
    fields = [(n, offsets.get(n, o), d) for n, o, d in HESAI_FIELDS]
    with pytest.raises(DataError, match="PointCloud2 layout"):
        decode_cloud(_msg(pts, fields), HEADER_NS, HESAI)
