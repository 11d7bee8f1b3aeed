"""Runner: resumable, forced stages redo downstream, failures isolated, executors agree."""

from __future__ import annotations

import io
from pathlib import Path

import cloudpickle
import pytest
from rich.console import Console

from pipeline.run.executors import DaskExecutor, LocalExecutor
from pipeline.run.runner import Runner
from schemas.config import parse_config
from schemas.manifest import read_manifest
from tests.pipeline.run import toy_stages
from tests.pipeline.run.toy_stages import STAGES


def _cfg(out: Path, retries: int = 1):  # type: ignore[no-untyped-def]
    return parse_config({"output_dir": str(out), "dag": {"retries": retries}})


def _counts(out: Path) -> dict[str, int]:
    return {p.stem: int(p.read_text()) for p in sorted((out / "first").glob("*.count"))}


def test_rerun_skips_completed_items(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    cfg = _cfg(tmp_path)
    first = Runner(cfg, STAGES, progress=False).run(LocalExecutor())
    told = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert told == ["second rec_c/0: rec_c.bag: /topic: one message refused"]
    assert [s.done for s in first] == [3, 3, 3] and first[1].rejected == 1
    second = Runner(cfg, STAGES, progress=False).run(LocalExecutor())
    assert [s.skipped for s in second] == [3, 3, 1] and [s.done for s in second] == [0, 0, 0]
    assert _counts(tmp_path) == {"rec_a": 1, "rec_b": 1, "rec_c": 1}
    manifest = read_manifest(tmp_path)
    assert manifest is not None
    assert set(manifest.stages["first"].items) == set(toy_stages.RECORDINGS)


def test_force_redoes_stage_and_downstream(tmp_path: Path) -> None:
    cfg = _cfg(tmp_path)
    Runner(cfg, STAGES, progress=False).run(LocalExecutor())
    forced = Runner(cfg, STAGES, progress=False).run(LocalExecutor(), force=["first"])
    assert [s.done for s in forced] == [3, 3, 3]
    assert _counts(tmp_path)["rec_a"] == 2


def test_failure_is_retried_reported_and_isolated(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TOY_FAIL", "rec_b")
    summaries = Runner(_cfg(tmp_path, retries=2), STAGES, progress=False).run(LocalExecutor())
    first, second, merge = summaries
    assert first.done == 2 and "rec_b" in first.failed
    assert "injected failure in rec_b" in first.failed["rec_b"]
    assert second.items == 2 and second.done == 2
    assert (tmp_path / "rec_a.second").exists() and not (tmp_path / "rec_b.second").exists()
    assert merge.done == 2  # built over the recordings that succeeded ...
    manifest = read_manifest(tmp_path)
    assert manifest is not None and "merge" not in manifest.stages  # ... but not marked done
    monkeypatch.delenv("TOY_FAIL")
    again = Runner(_cfg(tmp_path), STAGES, progress=False).run(LocalExecutor())
    assert again[0].done == 1 and again[0].skipped == 2 and again[1].done == 1
    assert again[2].done == 3 and (tmp_path / "merged.txt").read_text() == "rec_a,rec_b,rec_c"


def test_cross_recording_items_do_not_run_when_every_recording_failed(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TOY_FAIL", ",".join(toy_stages.RECORDINGS))
    monkeypatch.setenv("TOY_FAIL_KIND", "missing")
    first, second, merge = Runner(_cfg(tmp_path), STAGES, progress=False).run(LocalExecutor())
    assert len(first.failed) == 3 and first.done == 0
    assert second.items == 0 and merge.items == 0 and merge.done == 0
    assert not (tmp_path / "merged.txt").exists()  # no empty result that looks complete
    monkeypatch.setenv("TOY_FAIL", "rec_b")  # one recording left: the merge runs over it ...
    again = Runner(_cfg(tmp_path), STAGES, progress=False).run(LocalExecutor())
    assert again[2].done == 2 and (tmp_path / "merged.txt").read_text() == "rec_a,rec_c"
    manifest = read_manifest(tmp_path)
    assert manifest is not None and "merge" not in manifest.stages  # ... not marked done


def test_dask_cluster_matches_in_process(tmp_path: Path) -> None:
    cloudpickle.register_pickle_by_value(toy_stages)
    local_out, dask_out = tmp_path / "local", tmp_path / "dask"
    Runner(_cfg(local_out), STAGES, progress=False).run(LocalExecutor())
    executor = DaskExecutor(workers=2)
    try:
        Runner(_cfg(dask_out), STAGES, progress=False).run(executor)
    finally:
        executor.close()
    for path in sorted(local_out.glob("*.second")):
        assert path.read_text() == (dask_out / path.name).read_text()
    assert len(list(dask_out.glob("*.second"))) == 3


@pytest.mark.parametrize("executor_kind", ["local", "dask"])
def test_data_errors_are_not_retried_transient_ones_are(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, executor_kind: str) -> None:
    cloudpickle.register_pickle_by_value(toy_stages)
    monkeypatch.setenv("TOY_FAIL", "rec_b")
    # a library's ValueError (zarr's ContainsGroupError in a race) is not a data error
    # MissingInputError: a ValueError and a FileNotFoundError, which Dask could not carry back
    executor = LocalExecutor() if executor_kind == "local" else DaskExecutor(workers=1)
    try:
        runs = {kind: Runner(_cfg(tmp_path / kind, retries=2), STAGES, progress=False).run(
            executor)[0] for kind in ("data", "missing", "library", "transient")}
    finally:
        executor.close()
    for kind, attempts in (("data", 1), ("missing", 1), ("library", 3), ("transient", 3)):
        out, first = tmp_path / kind, runs[kind]  # the kind: the output folder's name
        assert (out / "first" / "rec_b.attempts").read_text() == str(attempts), kind
        error = {"data": "DataError", "missing": "MissingInputError",
                 "library": "ValueError"}.get(kind, "RuntimeError")
        assert first.failed["rec_b"] == f"{error}: injected failure in rec_b"
        assert first.done == 2


def test_changed_input_redoes_that_recording_downstream_and_cross_recording_items(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = _cfg(tmp_path)
    Runner(cfg, STAGES, progress=False).run(LocalExecutor())
    monkeypatch.setenv("TOY_INPUT_rec_b", "bag rewritten")  # like a bag's new mtime
    again = Runner(cfg, STAGES, progress=False).run(LocalExecutor())
    assert [(s.done, s.skipped) for s in again[:2]] == [(1, 2), (1, 2)]  # rec_b only ...
    assert again[2].done == 3 and again[2].skipped == 0  # ... and the merge over all of them
    assert _counts(tmp_path) == {"rec_a": 1, "rec_b": 2, "rec_c": 1}
    third = Runner(cfg, STAGES, progress=False).run(LocalExecutor())
    assert all(s.done == 0 for s in third)


def test_running_one_stage_alone_keeps_the_keys_of_a_full_run(tmp_path: Path) -> None:
    cfg = _cfg(tmp_path)
    Runner(cfg, STAGES, progress=False).run(LocalExecutor())
    alone = Runner(cfg, STAGES, progress=False).run(LocalExecutor(), only=["second"])
    assert [s.name for s in alone] == ["second"] and alone[0].skipped == 3
    assert alone[0].done == 0


def test_a_done_item_whose_table_is_cut_is_redone(tmp_path: Path,
                                                  caplog: pytest.LogCaptureFixture) -> None:
    """Was: a truncated selection.parquet was reported up to date, then a traceback."""
    import dataclasses

    import pyarrow as pa
    import pyarrow.parquet as pq

    def run_table(cfg, item):  # type: ignore[no-untyped-def]
        pq.write_table(pa.table({"x": [1, 2, 3]}), cfg.output_dir / f"{item.key}.parquet")
        return toy_stages.run_first(cfg, item)

    first = dataclasses.replace(STAGES[0], run=run_table,
                                outputs=lambda cfg, item: [cfg.output_dir / f"{item.key}.parquet"])
    stages = [first, *STAGES[1:]]
    cfg = _cfg(tmp_path)
    Runner(cfg, stages, progress=False).run(LocalExecutor())
    table = tmp_path / "rec_b.parquet"
    table.write_bytes(table.read_bytes()[:20])
    again = Runner(cfg, stages, progress=False).run(LocalExecutor())
    assert again[0].done == 1 and again[0].skipped == 2
    assert _counts(tmp_path) == {"rec_a": 1, "rec_b": 2, "rec_c": 1}
    assert any("rec_b.parquet" in r.getMessage() and "redoing it" in r.getMessage()
               for r in caplog.records)
    assert pq.read_table(table).num_rows == 3


def test_a_failed_stage_is_not_shown_done_nor_its_followers_up_to_date(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TOY_FAIL", ",".join(toy_stages.RECORDINGS))
    monkeypatch.setenv("TOY_FAIL_KIND", "missing")
    buf = io.StringIO()
    Runner(_cfg(tmp_path), STAGES, console=Console(file=buf, width=200)).run(LocalExecutor())
    lines = buf.getvalue().splitlines()
    assert lines[0] == "first: 0/3 (0 %), 0 s"
    assert lines[-3].startswith("first: 0/3 (0 %), 3 failed, ")
    assert "100 %" not in buf.getvalue() and "up to date" not in buf.getvalue()
    assert lines[-2:] == ["second   not run: 3 item(s) of a failed recording (fix it and rerun)",
                          "merge    not run: 1 item(s) of a failed recording (fix it and rerun)"]
