"""The ingest core's gated pass (`pipeline.ingest.core.gated_pass`): the bag path's stamp gate,
plausibility checks, rejects and accounting over stamped records of any source."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from pipeline.ingest.checks.rejects import Tally
from pipeline.ingest.core.gated_pass import GatedPass, Indexed, Record, check_notes, check_rows
from pipeline.ingest.errors import RowReject
from pipeline.ingest.index.ingest_result import index_writers
from schemas.config import ChecksConfig
from schemas.recording_index import REJECTS, Reason, read_index_table, table_path

MS = 1_000_000
STEP = 100 * MS  # 10 Hz


class Table:
    """An index table that keeps its rows (count and append, as IndexTableWriter)."""

    def __init__(self) -> None:
        self.rows: list[dict[str, object]] = []

    @property
    def count(self) -> int:
        return len(self.rows)

    def append(self, row: dict[str, object]) -> None:
        self.rows.append(row)


def _run(tmp_path: Path, records: list[Record], handle: Any, **kw: Any
         ) -> tuple[GatedPass, Table, list[dict[str, Any]]]:  # fmt: skip
    table, tally = Table(), Tally.empty()
    with index_writers(tmp_path) as out:
        gp = GatedPass(out, "lidar", ("data/lidar", "lidar"), "data/lidar/timestamp",
                       table, tally, **kw)  # type: ignore[arg-type]  # fmt: skip
        gp.run(records, handle)
    rejects = read_index_table(table_path(tmp_path, "rejects"), REJECTS).to_pylist()
    return gp, table, rejects


def _sweep(problem_at: set[int]) -> Any:
    def handle(i: int, stamp: int, _: Any) -> Indexed:
        bad = f"point 0 at 900 m (row {i})" if i in problem_at else None
        return Indexed({"stamp_ns": stamp, "ordinal": i}, f"f{i}", {"point_limits": bad})
    return handle


def test_stamp_gate_rejects_duplicate_unusable_and_gap(tmp_path: Path) -> None:
    stamps: list[int | RowReject] = [k * STEP for k in range(30)]
    stamps[5] = stamps[4]  # a duplicate stamp
    stamps[9] = RowReject(Reason.UNDECODABLE_MESSAGE, "data/lidar/timestamp", "row 9: NaN")
    stamps[20:] = [s + 2_000 * MS for s in stamps[20:]]  # type: ignore[operator]
    gp, table, rejects = _run(tmp_path, [Record(i, s) for i, s in enumerate(stamps)],
                              _sweep(set()))  # fmt: skip
    reasons = sorted(r["reason"] for r in rejects)
    assert reasons == ["duplicate_stamp", "stream_gap", "undecodable_message"]
    assert len(table.rows) == 28
    assert gp.tally.read[gp.key] == 30 and gp.tally.kept[gp.key] == 28
    assert gp.tally.rejected[gp.key] == 2  # a gap is not a record
    dup = next(r for r in rejects if r["reason"] == "duplicate_stamp")
    assert dup["file"] == "data/lidar/timestamp" and "row 5" in dup["detail"]


def test_sweep_checks_reject_one_implausible_sweep_and_number_the_rest(tmp_path: Path) -> None:
    records = [Record(i, i * STEP) for i in range(40)]
    gp, table, rejects = _run(tmp_path, records, _sweep({25}), kind="sweep", number="sweep",
                              checks=ChecksConfig())  # fmt: skip
    assert [(r["reason"], r["file"]) for r in rejects] == [("bad_pointcloud", "f25")]
    assert rejects[0]["detail"] == "point 0 at 900 m (row 25) (point_limits): a damaged message"
    assert [r["sweep"] for r in table.rows] == list(range(39))
    assert [r["ordinal"] for r in table.rows] == [i for i in range(40) if i != 25]
    rows = check_rows([gp])
    assert (rows[0]["check"], rows[0]["messages"], rows[0]["rejected"]) == ("point_limits", 40, 1)


def test_a_check_that_does_not_fit_is_switched_off_not_rejecting(tmp_path: Path) -> None:
    gp, table, rejects = _run(tmp_path, [Record(i, i * STEP) for i in range(30)],
                              _sweep(set(range(0, 30, 2))), kind="sweep",
                              checks=ChecksConfig())  # fmt: skip
    assert rejects == [] and len(table.rows) == 30
    assert check_rows([gp])[0]["state"] == "off" and len(check_notes([gp])) == 1


@pytest.mark.parametrize("enabled", [True, False])
def test_pose_jump_is_bad_pose_when_checks_are_on(tmp_path: Path, enabled: bool) -> None:
    def handle(i: int, stamp: int, _: Any) -> Indexed:
        x = 1000.0 if i == 12 else 0.1 * i  # 1 m/s, one pose 1 km away
        return Indexed({"stamp_ns": stamp, "position": [x, 0.0, 0.0]}, "poses.txt",
                       {"quat_norm": None})
    gp, table, rejects = _run(tmp_path, [Record(i, i * STEP) for i in range(30)], handle,
                              kind="pose", checks=ChecksConfig(enabled=enabled))  # fmt: skip
    assert [r["reason"] for r in rejects] == (["bad_pose"] if enabled else [])
    assert len(table.rows) == (29 if enabled else 30)
    assert [r["check"] for r in check_rows([gp])] == (["quat_norm", "pose_jump"] if enabled else [])


def test_handler_reject_names_its_file(tmp_path: Path) -> None:
    def handle(i: int, stamp: int, _: Any) -> Indexed:
        if i == 3:
            raise RowReject(Reason.EMPTY_SWEEP, "x/3.bin", "x/3.bin: no valid points")
        return Indexed({"stamp_ns": stamp}, f"x/{i}.bin")
    gp, table, rejects = _run(tmp_path, [Record(i, i * STEP) for i in range(8)], handle)
    assert [(r["reason"], r["file"], r["topic"]) for r in rejects] == [
        ("empty_sweep", "x/3.bin", "lidar")]
    assert len(table.rows) == 7 and gp.tally.rejected[gp.key] == 1


def test_a_stream_whose_every_record_is_refused_writes_no_check_rows(tmp_path: Path) -> None:
    """Every sweep refused by its handler (an empty sweep each): each is a reject with its
    reason, none is indexed, and the stream's checks, made when a record first reaches them,
    are never made: no check rows, no notes (one rule for bags, HF and KITTI-360)."""
    def handle(i: int, stamp: int, _: Any) -> Indexed:
        raise RowReject(Reason.EMPTY_SWEEP, f"x/{i}.bin", f"x/{i}.bin: no valid points")
    gp, table, rejects = _run(tmp_path, [Record(i, i * STEP) for i in range(12)], handle,
                              kind="sweep", number="sweep", checks=ChecksConfig())  # fmt: skip
    assert [r["reason"] for r in rejects] == ["empty_sweep"] * 12 and table.rows == []
    assert gp.tally.read[gp.key] == 12 and gp.tally.rejected[gp.key] == 12
    assert gp.checked is None and check_rows([gp]) == [] and check_notes([gp]) == []


def test_a_stream_across_files_is_accounted_by_file(tmp_path: Path) -> None:
    """The bags' use (`spans_files`): records pushed from two files into one topic's pass; a
    refusal names its own file with the gate's detail, a gap the file it ends in; every record
    read is kept or rejected under (its file, topic), rejects counted by the reject log."""
    table = Table()
    with index_writers(tmp_path) as out:
        gp = GatedPass(out, "lidar", ("", "lidar"), "", table, out.tally,  # type: ignore[arg-type]
                       kind="sweep", number="sweep", checks=ChecksConfig(), spans_files=True)
        gp.handle = lambda i, stamp, _: Indexed({"stamp_ns": stamp, "ordinal": i},
                                                "a.bag" if i < 10 else "b.bag", {})
        stamps = [k * STEP for k in range(24)]
        stamps[13] = stamps[12]  # a duplicate in the second file
        stamps[18:] = [s + 2_000 * MS for s in stamps[18:]]  # a gap in the second file
        for i, s in enumerate(stamps):
            file = "a.bag" if i < 10 else "b.bag"
            gp.push(Record(i, s, None, file))
            if i in (9, 23):
                gp.end_gate(file)
        gp.end_checks()
        tally = out.tally
    rejects = read_index_table(table_path(tmp_path, "rejects"), REJECTS).to_pylist()
    by = {r["reason"]: r for r in rejects}
    assert set(by) == {"duplicate_stamp", "stream_gap"}
    assert by["duplicate_stamp"]["file"] == "b.bag" and by["stream_gap"]["file"] == "b.bag"
    assert by["duplicate_stamp"]["detail"].startswith("stamp ")  # the gate's own wording
    assert [r["sweep"] for r in table.rows] == list(range(23))
    assert tally.read == {("a.bag", "lidar"): 10, ("b.bag", "lidar"): 14}
    assert tally.kept == {("a.bag", "lidar"): 10, ("b.bag", "lidar"): 13}
    assert tally.unaccounted() == {}
    assert [r["check"] for r in check_rows([gp])] == ["point_limits", "ring_elevation",
                                                      "rotation"]
