"""The run policy (pipeline.run.service): refusals before the lock, the lock, verify, events."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from pipeline.run.lock import acquire_output
from pipeline.run.service import RunError, RunEvents, RunHooks, RunRequest, run_stages
from schemas.config import parse_config
from tests.pipeline.run.toy_stages import STAGES


def _cfg(out: Path, recordings: list[str] | None = None):  # type: ignore[no-untyped-def]
    return parse_config({"output_dir": str(out), "ingest": {"recordings": recordings or []}})


class _Seen(RunEvents):
    def __init__(self) -> None:
        self.verified_with: list[Any] = []

    def verified(self, result: Any) -> None:
        self.verified_with.append(result)


def test_a_run_through_the_service_runs_every_stage_and_resumes(tmp_path: Path) -> None:
    first = run_stages(_cfg(tmp_path), STAGES)
    again = run_stages(_cfg(tmp_path), STAGES)
    assert [s.name for s in first.summaries] == [s.name for s in STAGES]
    assert sum(s.done for s in first.summaries) > 0
    assert all(s.done == 0 and s.skipped == s.items for s in again.summaries)


def test_an_unknown_stage_is_refused_with_exit_code_2_before_any_lock(tmp_path: Path) -> None:
    with pytest.raises(RunError, match="unknown stage 'nope'; stages are first") as err:
        run_stages(_cfg(tmp_path), STAGES, RunRequest(force=("nope",)))
    assert err.value.exit_code == 2
    assert not (tmp_path / "manifest.json").exists()


def test_a_recording_that_is_not_a_folder_is_refused_with_exit_code_2(tmp_path: Path) -> None:
    missing = tmp_path / "rec_gone"
    with pytest.raises(RunError, match="rec_gone is not a folder") as err:
        run_stages(_cfg(tmp_path / "out", [str(missing)]), STAGES)
    assert err.value.exit_code == 2


def test_a_held_lock_refuses_the_run_and_a_released_one_lets_it_go(tmp_path: Path) -> None:
    lock = acquire_output(tmp_path)
    try:
        with pytest.raises(RunError) as err:
            run_stages(_cfg(tmp_path), STAGES)
        assert err.value.exit_code == 1
    finally:
        lock.release()
    assert run_stages(_cfg(tmp_path), STAGES).summaries


def test_verify_runs_its_hook_under_the_lock_before_the_stages(tmp_path: Path) -> None:
    calls: list[tuple[Path, bool]] = []

    def verify(out: Path) -> str:
        calls.append((out, (out / "manifest.json").exists()))
        return "report"

    seen = _Seen()
    outcome = run_stages(_cfg(tmp_path), STAGES, RunRequest(verify=True), RunHooks(verify=verify),
                         seen)
    assert calls == [(tmp_path, False)]  # before the runner wrote its manifest
    assert outcome.verified == "report" and seen.verified_with == ["report"]
    plain = run_stages(_cfg(tmp_path), STAGES, RunRequest(), RunHooks(verify=verify))
    assert plain.verified is None and len(calls) == 1


def test_failures_count_failed_items_and_unless_allowed_empty_recordings(tmp_path: Path) -> None:
    outcome = run_stages(_cfg(tmp_path), STAGES)
    outcome.empty = ["rec_x: no usable view"]
    assert outcome.failures() == len(outcome.failed) + 1
    assert outcome.failures(allow_empty=True) == len(outcome.failed)
