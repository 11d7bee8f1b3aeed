"""How the bench judges a camera's verdict under a fault or on clean data
(`pipeline.analysis.geometry_faults.judged`); the faults themselves are proven in
test_geometry_check.py on one recording."""

from __future__ import annotations

from packets.geometry_verdict import FAILED, INCONCLUSIVE, OK, Verdict
from pipeline.analysis.geometry_faults import judged


def test_judged_verdicts() -> None:
    assert judged(Verdict(FAILED, "x"), False) == "false_fail"
    assert judged(Verdict(INCONCLUSIVE, "few views"), False) == "ok"
    assert judged(Verdict(OK, "x"), True) == "missed"
    assert judged(Verdict(INCONCLUSIVE, "better offset"), True) == "detected"
    assert judged(Verdict(INCONCLUSIVE, ""), True) == "missed"
    assert judged(Verdict(FAILED, "x"), True) == "detected"
