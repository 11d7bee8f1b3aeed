"""CLI: every command has --help; stats, plot and align work over a real output."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import typer
from typer.main import get_command
from typer.testing import CliRunner

from cli.app import app


def _paths(cmd: object, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    subs = getattr(cmd, "commands", {})
    out = [prefix]
    for name, sub in subs.items():
        out.extend(_paths(sub, (*prefix, name)))
    return out


@pytest.mark.parametrize("path", _paths(get_command(app)))
def test_every_command_has_help(path: tuple[str, ...]) -> None:
    result = CliRunner().invoke(app, [*path, "--help"])
    assert result.exit_code == 0, result.output
    assert "Usage" in result.output


def test_command_set_is_complete() -> None:
    names = {p[0] for p in _paths(get_command(app)) if p}
    assert {"run", "demo", "config", "stats", "bench", "synth", "ingest", "select", "plot",
            "align", "train", "sample", "eval", "accuracy", "unlock", "view", "report",
            "verify"} <= names
    benches = {p[1] for p in _paths(get_command(app)) if len(p) == 2 and p[0] == "bench"}
    assert benches == {"cache", "packets", "ingest", "packing", "dag", "synth", "costs",
                       "sampler", "loader", "tradeoffs", "fuzz", "view", "science", "storage",
                       "variants", "ddp"}
    assert isinstance(app, typer.Typer)


def test_bench_synth_prints_json() -> None:
    result = CliRunner().invoke(app, ["bench", "synth", "--json", "--seconds", "0.5"])
    assert result.exit_code == 0, result.output
    figures = json.loads(result.stdout)
    assert figures["synth_wall_s"] > 0 and figures["over_floor"] > 0


def test_unknown_stage_to_force_is_an_error(tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {tmp_path / 'out'}\ndag: {{executor: local}}\n"
                   f"ingest: {{recordings: [{tmp_path / 'none'}]}}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local", "--force", "nope"])
    assert result.exit_code == 2
    assert "unknown stage 'nope'" in result.output


def test_known_stage_to_force_is_accepted(tmp_path: Path) -> None:
    cfg = _config(tmp_path, NOTHING_TO_DO)
    result = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local", "--force", "encode",
                                      "--only", "clips"])
    assert result.exit_code == 0, result.output
    assert "unknown stage" not in result.output
    assert "│ clips " in result.output and "│ encode " not in result.output  # --only: clips


NOTHING_TO_DO = "ingest: {recordings: []}\nsynth: {scenes: []}\n"
"""No recordings and no synthetic scenes: every stage has nothing to do."""


def _config(tmp_path: Path, extra: str = "", out: Path | None = None) -> Path:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {out or tmp_path / 'out'}\n{extra}")
    return cfg


def test_missing_recording_is_refused_before_any_work(tmp_path: Path) -> None:
    cfg = _config(tmp_path, f"ingest: {{recordings: [{tmp_path / 'nope'}]}}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    assert result.exit_code == 2
    assert f"ingest.recordings: {tmp_path / 'nope'} is not a folder" in " ".join(
        result.output.split())
    assert not (tmp_path / "out" / "manifest.json").exists()


@pytest.mark.filterwarnings("ignore")  # dask.distributed's own shutdown warnings
def test_mission_without_bags_fails_in_the_same_line_under_every_executor(tmp_path: Path) -> None:
    mission = tmp_path / "mission_a"
    mission.mkdir()
    want = (f"failed ingest mission_a: MissingInputError: {mission}: no ROS1 .bag files, .mcap "
            "files or ROS2 bag folders (empty)")
    for executor in ("--local", "dask"):
        out = tmp_path / executor.strip("-")
        cfg = _config(tmp_path, f"ingest: {{recordings: [{mission}]}}\ndag: {{workers: 1}}\n", out)
        result = CliRunner().invoke(app, ["-c", str(cfg), "run", *[executor][:executor != "dask"]])
        text = " ".join(result.output.split())
        assert result.exit_code == 1, text
        assert want in text and "Traceback" not in text and "TypeError" not in text, text
        # nothing downstream ran for it: no empty cache or clip index that looks complete
        assert not (out / "cache.zarr").exists() and not (out / "clips.parquet").exists()


def test_held_lock_is_refused_before_workers_start(tmp_path: Path) -> None:
    from pipeline.run.lock import OutputLock

    cfg = _config(tmp_path, NOTHING_TO_DO)
    with OutputLock(tmp_path / "out"):  # this live process holds it
        result = CliRunner().invoke(app, ["-c", str(cfg), "run"])
    assert result.exit_code == 1
    assert "locked by another m3gd run" in result.output and "Traceback" not in result.output


def test_bad_sql_is_one_line(tmp_path: Path) -> None:
    from pipeline.stats.merge import merge_recording
    from tests.pipeline.stats.test_stats import _write_shards

    _write_shards(tmp_path / "out")
    merge_recording(tmp_path / "out", "rec")
    cfg = _config(tmp_path)
    result = CliRunner().invoke(app, ["-c", str(cfg), "stats", "query",
                                      "SELECT nope FROM view_stats"])
    assert result.exit_code == 1
    assert "nope" in result.output and len(result.output.strip().splitlines()) <= 3


def test_plot_without_output_is_an_error_and_writes_nothing(tmp_path: Path) -> None:
    cfg = _config(tmp_path)
    result = CliRunner().invoke(app, ["-c", str(cfg), "plot"])
    assert result.exit_code == 1 and "run the pipeline first" in result.output
    assert not (tmp_path / "out").exists()


def _empty_run_config(tmp_path: Path, out: Path) -> Path:
    """A config writing to `out` in which every stage has nothing to do."""
    return _config(tmp_path, NOTHING_TO_DO, out)


def test_unusable_output_folder_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "afile").write_text("not a folder")
    cfg = _empty_run_config(tmp_path, tmp_path / "afile" / "out")
    result = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    assert result.exit_code == 1
    assert "cannot be used as the output folder: Not a directory" in result.output
    assert "Traceback" not in result.output


def test_cache_of_an_older_format_is_refused_in_one_line_with_the_fix(tmp_path: Path) -> None:
    out = tmp_path / "out"
    (out / "cache.zarr").mkdir(parents=True)
    (out / "cache.zarr" / "zarr.json").write_text(json.dumps(
        {"zarr_format": 3, "node_type": "group",
         "attributes": {"m3gd_kind": "cache", "m3gd_format_version": 1}}))
    result = CliRunner().invoke(app, ["-c", str(_empty_run_config(tmp_path, out)), "run",
                                      "--local"])
    assert result.exit_code == 2
    assert "cache format version 1 is not supported" in result.output
    assert f"rm -r {out / 'cache.zarr'} {out / 'cache_done'} && m3gd run --force ingest" in (
        result.output.replace("\n", ""))
    assert "Traceback" not in result.output


def test_interrupted_run_says_how_to_resume_and_frees_the_lock(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from pipeline.run.runner import Runner

    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(Runner, "run", interrupted)
    cfg = _empty_run_config(tmp_path, tmp_path / "out")
    result = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    assert result.exit_code == 130
    assert "interrupted: finished items are kept; run the same command again" in result.output
    assert not (tmp_path / "out" / ".m3gd.lock").exists()
    monkeypatch.undo()
    again = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    assert again.exit_code == 0, again.output  # the lock was released
