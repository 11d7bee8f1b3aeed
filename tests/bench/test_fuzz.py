"""Fuzzing ingest with damaged bags (hypothesis, seeded): the contract holds in every case.

The short run (8 cases) is in the default suite; the long one (200 cases) is marked slow.
Invariants: no crash (a refusal is a one-line ValueError naming the bag or topic), the
accounting holds, no message is lost silently, no NaN/Inf reaches the index or the cache, and
where no byte of a message changed (truncation, chunk swaps) nothing differs from the clean
twin. The fuzzed bags' LZ4 chunks carry the checksum `rosbag record` writes, so a flipped byte
is a damaged chunk. Without a checksum (uncompressed chunks, the `raw_twin` tests) targeted
flips of a point, a position and a quaternion are caught by the plausibility checks;
`m3gd bench fuzz --compression lz4|none` counts what still gets through.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from bench.fuzz import (
    BAGS,
    LIDAR,
    ODOM,
    CaseResult,
    Outputs,
    Twin,
    ingest_outputs,
    make_base,
    run_case,
    run_fuzz,
)
from bench.support.fuzz_cases import MUTATIONS
from pipeline.ingest.sources.pointcloud import cloud_array
from schemas.recording_index import REJECTS, read_index_table, table_path


@pytest.fixture(scope="module")
def twin(tmp_path_factory: pytest.TempPathFactory) -> Twin:
    work = tmp_path_factory.mktemp("fuzz")
    return Twin.of(make_base(work / "base_root"), work)


def _check(r: CaseResult) -> None:
    where = f"{r.bag} {r.mutation} seed {r.seed}: {r.what}"
    assert not r.crash, f"{where}: {r.crash}"
    if r.refused:
        assert "\n" not in r.refused and (".bag" in r.refused or "/" in r.refused), where
        return
    assert r.accounting_gaps == 0 and r.silent_losses == 0 and r.nonfinite == 0, where
    assert r.good_rejected == 0, where  # the plausibility checks refuse no intact message
    if r.mutation in ("truncate", "shuffle"):  # no byte of any message was changed
        assert r.damaged_images == r.damaged_sweeps == r.damaged_poses == 0, where


CASE = {"bag": st.sampled_from(BAGS), "mutation": st.sampled_from(sorted(MUTATIONS)),
        "seed": st.integers(0, 2**31 - 1)}  # fmt: skip


def _fuzz(examples: int) -> Callable[..., None]:
    """A seeded fuzz test of `examples` cases (hypothesis, derandomized)."""

    @settings(max_examples=examples, deadline=None, derandomize=True,
              suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
    @given(**CASE)
    def fuzz(twin: Twin, tmp_path_factory: pytest.TempPathFactory, bag: str, mutation: str,
             seed: int) -> None:  # fmt: skip
        _check(run_case(twin, bag, mutation, seed, tmp_path_factory.getbasetemp() / "cases"))

    return fuzz


test_fuzz_short = _fuzz(8)
test_fuzz_long = pytest.mark.slow(_fuzz(200))


def test_first_chunk_flip_of_each_sensor(twin: Twin, tmp_path: Path) -> None:
    """The audit's case for every bag: 30 bytes flipped inside the first chunk."""
    results = [run_case(twin, bag, "flip_first_chunk", 7, tmp_path) for bag in BAGS]
    assert [r.bag for r in results] == list(BAGS)
    for r in results:
        _check(r)
        # the audit's loss: a damaged first chunk must not lose the bag's messages silently
        assert not r.crash and r.silent_losses == 0 and r.accounting_gaps == 0, r


def test_bench_figures(tmp_path: Path) -> None:
    figures = run_fuzz(tmp_path, max_cases=4, seconds=60, lock_trials=1, lock_starts=3,
                       hf_cases=2, cache_flips=5, repair_rounds=0, table_rounds=0)
    assert figures["cases_tried"] == 4 and figures["lock_starts"] == 6
    assert figures["hf_cases"] == 2 and figures["cache_flips"] == 5
    for key in ("crashes", "silent_losses", "accounting_gaps", "lock_double_holds",
                "nonfinite_values", "intact_messages_rejected_by_checks", "hf_crashes",
                "silent_cache_corruptions", "cache_flips_missed_by_verify"):
        assert figures[key] == 0, (key, figures)
    assert {"damaged_views_cached", "damaged_sweeps_indexed", "refused_in_one_line"} <= set(figures)


@pytest.fixture(scope="module")
def raw_twin(tmp_path_factory: pytest.TempPathFactory) -> Twin:
    """The twin with uncompressed chunks: a flipped byte is a flipped message byte."""
    work = tmp_path_factory.mktemp("fuzz_none")
    return Twin.of(make_base(work / "base_root", compression="none"), work)


def _raw_message(bag: Path, topic: str, index: int) -> bytes:
    """The serialized bytes of message `index` of `topic` in an intact ROS1 bag."""
    from rosbags.rosbag1 import Reader

    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        return [raw for _, _, raw in reader.messages(connections=conns)][index]


Rows = list[dict[str, Any]]


def _flipped_case(twin: Twin, bag: str, offset_in: Callable[[bytes], int], topic: str,
                  tmp: Path, xor: int = 0x40, index: int = 3) -> tuple[Outputs, Rows]:  # fmt: skip
    """Ingest the twin's mission with one byte of one message XORed (uncompressed bag)."""
    mission = tmp / "base"
    mission.mkdir(parents=True)
    for src in twin.mission.glob("*.bag"):
        (mission / src.name).hardlink_to(src)
    target = mission / f"base_{bag}.bag"
    data = bytearray(target.read_bytes())
    raw = _raw_message(target, topic, index)
    at = bytes(data).find(raw)
    assert at > 0 and bytes(data).find(raw, at + 1) < 0
    data[at + offset_in(raw)] ^= xor
    target.unlink()
    target.write_bytes(bytes(data))
    got, idx = ingest_outputs(mission, tmp / "out")
    rejects = read_index_table(table_path(idx, "rejects"), REJECTS).to_pylist()
    return got, rejects


def _odom_offset(raw: bytes, field: int) -> int:
    """Byte offset of float64 number `field` of the pose (x y z, qx qy qz qw) in an Odometry."""
    (frame_len,) = struct.unpack_from("<I", raw, 12)
    (child_len,) = struct.unpack_from("<I", raw, 16 + frame_len)
    return 20 + frame_len + child_len + 8 * field


@pytest.mark.parametrize("xor", [0x80, 0x01])
def test_point_flip_in_raw_bag_is_rejected(raw_twin: Twin, tmp_path: Path, xor: int) -> None:
    """One LiDAR point's x negated (sign bit) or scaled by 4 or 1/4 (exponent): finite and in
    range, so before the checks the sweep was indexed with the point moved; now it is rejected
    naming file, topic and stamp."""
    raw = _raw_message(raw_twin.mission / "base_hesai_undist.bag", LIDAR, 3)
    msg = get_typestore(Stores.ROS1_NOETIC).deserialize_ros1(raw, "sensor_msgs/msg/PointCloud2")
    arr, width = cloud_array(msg), int(msg.point_step)
    rho = np.hypot(arr["x"], arr["y"])
    # x and y both large: scaling x turns the point (along its own ray it would be a plausible
    # return at another range, which no check can tell)
    ratio = np.abs(arr["x"]) / rho
    k = int(np.flatnonzero((ratio > 0.55) & (ratio < 0.8) & (rho > 3))[0])
    start = len(raw) - 1 - arr.size * width  # the data array, then one byte (is_dense)
    got, rejects = _flipped_case(raw_twin, "hesai_undist", lambda r: start + k * width + 3,
                                 LIDAR, tmp_path, xor=xor)  # fmt: skip
    (bad,) = [r for r in rejects if r["topic"] == LIDAR]
    assert bad["reason"] == "bad_pointcloud" and bad["file"] == "base_hesai_undist.bag"
    assert f"first point {k}" in bad["detail"] and bad["stamp_ns"] not in got.sweeps
    assert all(raw_twin.outputs.sweeps[s] == v for s, v in got.sweeps.items())


@pytest.mark.parametrize(("field", "byte"), [(0, 6), (6, 6)])
def test_pose_flip_in_raw_bag_is_rejected(raw_twin: Twin, tmp_path: Path, field: int,
                                          byte: int) -> None:  # fmt: skip
    """Byte 6 of position x (a jump) or of quaternion w (norm off 1) flipped: before the checks
    the pose was indexed (w silently re-normalized); now it is rejected as bad_pose."""
    def offset(raw: bytes) -> int:
        return _odom_offset(raw, field) + byte

    got, rejects = _flipped_case(raw_twin, "anymal_state", offset, ODOM, tmp_path)
    (bad,) = [r for r in rejects if r["topic"] == ODOM]
    assert bad["reason"] == "bad_pose" and bad["file"] == "base_anymal_state.bag"
    assert bad["stamp_ns"] not in got.poses
    assert len(got.poses) == len(raw_twin.outputs.poses) - 1
    assert all(np.allclose(v, raw_twin.outputs.poses[s], rtol=0, atol=1e-9)
               for s, v in got.poses.items())  # fmt: skip


def test_bench_figures_over_sensor_variants(tmp_path: Path) -> None:
    """The fuzz contract also holds on recordings of other sensors (a Livox-like scan whose
    rotation check is switched off, missing returns as x-only NaN in an organized cloud)."""
    figures = run_fuzz(tmp_path, max_cases=4, seconds=90, lock_trials=1, lock_starts=2,
                       variants=["livox", "missing_x_nan"], repair_rounds=0,
                       table_rounds=0)  # fmt: skip
    assert figures["cases_tried"] == 4 and figures["variants"] == ["livox", "missing_x_nan"]
    for key in ("crashes", "silent_losses", "accounting_gaps", "lock_double_holds",
                "nonfinite_values", "intact_messages_rejected_by_checks"):
        assert figures[key] == 0, (key, figures)


@pytest.mark.slow
def test_fuzz_over_every_variant(tmp_path: Path) -> None:
    from pipeline.synth.variants import VARIANTS

    figures = run_fuzz(tmp_path, max_cases=2 * len(VARIANTS), seconds=1800, lock_trials=1,
                       lock_starts=2, variants=list(VARIANTS))  # fmt: skip
    for key in ("crashes", "silent_losses", "accounting_gaps", "nonfinite_values",
                "intact_messages_rejected_by_checks"):
        assert figures[key] == 0, (key, figures["failures"])
