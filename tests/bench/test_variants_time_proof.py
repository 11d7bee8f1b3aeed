"""The point-time proof bench (`bench.variants_time_proof`): its figures count what they say,
and on a header-stamped and a first-point-stamped variant the proof keeps the truth."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.variants_time_proof import time_proof_row, time_proof_summary, time_variants
from pipeline.inspect.prove_time import reference_of


def _row(truth: str, status: str, kept: str, reversed_: str | None = None,
         reversed_kept: str = "") -> dict[str, object]:
    row: dict[str, object] = {"variant": "v", "truth": truth, "inferred": truth,
                              "status": status, "kept": kept, "note": "",
                              "proof_seconds": 1.0, "without_time_seconds": 0.6}
    if reversed_ is not None:
        row |= {"declared_reversed": reversed_, "declared_reversed_kept": reversed_kept}
    return row


def test_a_wrong_convention_kept_is_counted_whichever_way_it_was_declared() -> None:
    def c(ref: str) -> str:
        return f"ns {ref} (header at the sweep's end)"

    rows = [_row("header", "proven", c("header"), "switched", c("header")),
            _row("first_point", "unproven", c("first_point"), "unproven", c("header")),
            _row("absolute", "unproven", c("absolute")),
            _row("header", "proven", c("first_point"), "proven", c("first_point"))]
    got = time_proof_summary(rows)
    assert got["point_time_variants"] == 4 and got["point_time_proven"] == 2
    assert got["point_time_declared_reversed"] == 3
    assert got["point_time_reversed_switched"] == 1
    # the last row proved first_point twice on a header recording; the unproven one kept
    # nothing it claims
    assert got["point_time_wrong_proven"] == 2
    assert got["point_time_seconds_median"] == pytest.approx(0.4)


def test_every_time_group_variant_is_in_the_bench() -> None:
    from pipeline.synth.variants import GROUPS

    assert set(GROUPS["time"]) <= set(time_variants())
    assert {"default", "vlp16"} <= set(time_variants())


@pytest.mark.slow
@pytest.mark.parametrize("name", ["time_float64_s_header", "time_float32_s_first_point"])
def test_the_proof_keeps_the_truth_and_switches_the_reversed_declaration(
        tmp_path: Path, name: str) -> None:
    synth = {"seconds": 3.0, "image_width": 192, "image_height": 128,
             "points_per_sweep": 8192, "cameras": ["front"]}
    row = time_proof_row(tmp_path, name, synth)
    assert row["inferred"] == row["truth"], row
    assert row["status"] == "proven" and reference_of(row["kept"]) == row["truth"], row
    assert row["declared_reversed"] == "switched", row
    assert reference_of(row["declared_reversed_kept"]) == row["truth"], row
    assert time_proof_summary([row])["point_time_wrong_proven"] == 0
