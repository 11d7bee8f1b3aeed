"""Messages that read well anywhere: progress lines when redirected, tables never cut, counts
that belong to their stage, JSON summaries, hints that carry the needed options."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from cli.app import app
from schemas.config import M3GDConfig
from schemas.tables import QUERYABLE

TINY = """output_dir: {out}
synthetic: true
synth: {{scenes: [corridor], seconds: 1.5, cameras: [front], image_width: 168,
        image_height: 112, points_per_sweep: 1024}}
ingest: {{out_height: 56, out_width: 84}}
encoders: {{image_channels: 16, point_channels: 8}}
cache: {{shard_views: 8}}
dag: {{executor: local}}
"""


def m3gd(cfg: Path, *args: str, code: int = 0) -> tuple[str, str]:
    """(stdout, stderr) of `m3gd -c cfg args` (CliRunner: neither stream is a terminal)."""
    result = CliRunner().invoke(app, ["-c", str(cfg), *args])
    assert result.exit_code == code, result.output
    return result.stdout, result.stderr


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str, str]:
    """(config, stdout, stderr) of a tiny synthetic run."""
    where = tmp_path_factory.mktemp("msg")
    cfg = where / "tiny.yaml"
    cfg.write_text(TINY.format(out=where / "out"))
    out, err = m3gd(cfg, "run")
    return cfg, out, err


def _row(table: str, stage: str) -> list[str]:
    """Cells of one stage's row of the run summary table."""
    line = next(ln for ln in table.splitlines() if re.match(rf"[│|]\s*{stage}\s", ln))
    return [c.strip() for c in re.split(r"[│|]", line)[1:-1]]


def test_redirected_run_prints_progress_lines_per_stage(tiny: tuple[Path, str, str]) -> None:
    _, _, err = tiny
    for stage in ("synth", "ingest", "select", "encode", "packets", "stats", "clips"):
        assert re.search(rf"^{stage}\s*: \d+/\d+ \(100 %\), \d+ s$", err, re.M), (stage, err)
    assert "━" not in err  # no bar drawn into a file


def test_run_summary_counts_rejects_under_the_stage_that_refused(
        tiny: tuple[Path, str, str]) -> None:
    _, out, _ = tiny
    cols = ["stage", "tasks", "up to date", "failed", "outputs", "rejected", "seconds"]
    select = dict(zip(cols, _row(out, "select"), strict=True))
    encode = dict(zip(cols, _row(out, "encode"), strict=True))
    stats = dict(zip(cols, _row(out, "stats"), strict=True))
    ingest = dict(zip(cols, _row(out, "ingest"), strict=True))
    views = int(ingest["outputs"])
    assert int(select["rejected"]) > 0  # the tiny run has views beyond the Δτ bound
    assert int(select["outputs"]) + int(select["rejected"]) == views
    assert int(encode["rejected"]) == 0 and encode["outputs"] == select["outputs"]
    assert int(stats["outputs"]) == views  # one view_stats row per view, nothing else


def test_tables_are_not_cut_when_piped(tiny: tuple[Path, str, str]) -> None:
    cfg, _, _ = tiny
    out, _ = m3gd(cfg, "stats", "summary", "dtau")
    assert "synth_corridor_s0" in out and "max_abs_dtau_rejected_ms" in out
    assert "…" not in out


def test_stats_summary_json_is_one_line_per_row_of_every_report(
        tiny: tuple[Path, str, str]) -> None:
    cfg, _, _ = tiny
    rows = [json.loads(line)
            for line in m3gd(cfg, "stats", "summary", "--json")[0].splitlines()]
    names = {r["summary"] for r in rows}  # JSON Lines: one object per row, its report named
    assert {"dtau", "occupancy", "rejects"} <= names <= {
        "dtau", "occupancy", "sparse_views", "rejects", "checks"}
    rejects = [r for r in rows if r["summary"] == "rejects"]
    assert rejects[0]["reject_reason"] == "dtau_exceeded"
    one = [json.loads(line)
           for line in m3gd(cfg, "stats", "summary", "dtau", "--json")[0].splitlines()]
    assert {r["summary"] for r in one} == {"dtau"} and one[0]["recording"] == "synth_corridor_s0"
    assert len(one) == len([r for r in rows if r["summary"] == "dtau"])
    assert len(rows) > len(names)  # some report has several rows: one line each


def test_stats_query_help_lists_every_table_with_its_command() -> None:
    text = " ".join(CliRunner().invoke(app, ["stats", "query", "--help"]).output.split())
    tables = ("view_stats", "cell_stats", "clips", "alignment", "accuracy",
              "reprojection_consistency")
    for name in tables:
        assert f"{name}:" in text
    assert "`m3gd align`" in text and "`m3gd accuracy`" in text
    assert "`m3gd align --consistency`" in text
    assert set(QUERYABLE) == set(tables)


def test_align_prints_progress_then_its_table_is_queryable(tiny: tuple[Path, str, str]) -> None:
    cfg, _, _ = tiny
    _, err = m3gd(cfg, "align")
    assert re.search(r"^align views: (\d+)/\1 \(100 %\)", err, re.M), err
    out, _ = m3gd(cfg, "stats", "query", "--json",
                  "SELECT pair, metric FROM alignment ORDER BY metric LIMIT 1")
    assert json.loads(out)["pair"] == "latents_l0:h"


def test_a_table_not_written_yet_names_the_command_that_writes_it(
        tiny: tuple[Path, str, str]) -> None:
    cfg, _, _ = tiny
    # the module's output is shared: `m3gd accuracy` of another test may already have run
    shutil.rmtree(cfg.parent / "out" / "stats" / "accuracy", ignore_errors=True)
    out, err = m3gd(cfg, "stats", "query", "SELECT count(*) FROM accuracy", code=1)
    assert "table accuracy is written by `m3gd accuracy`: run it first" in out + err


def test_eval_of_a_mode_folder_suggests_training_in_that_mode(
        tiny: tuple[Path, str, str]) -> None:
    cfg, _, _ = tiny
    ckpt = cfg.parent / "out" / "train" / "geom_only"
    out, err = m3gd(cfg, "eval", str(ckpt), code=1)
    assert f"m3gd train --mode geom_only --out {ckpt}" in " ".join((out + err).split())


def test_synth_writes_to_output_dir_by_default_and_prints_a_table(tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(TINY.format(out=tmp_path / "out"))
    out, _ = m3gd(cfg, "synth", "--seconds", "0.5", "--scene", "plaza")
    mission = tmp_path / "out" / "recordings" / "synth_plaza_s0"  # as `m3gd run` names it
    assert (mission / "groundtruth").is_dir()
    assert "synthesized mission synth_plaza_s0" in out and "SynthResult(" not in out
    assert "sweeps" in out and str(mission) in out


def test_synth_faults_help_lists_every_fault_and_a_bad_one_names_them() -> None:
    from cli.stages import _fault_names

    names = _fault_names()
    assert "corrupt_jpeg" in names and "lidar_gap" in names
    text = " ".join(CliRunner().invoke(app, ["synth", "--help"]).output.split())
    for name in names:
        assert name in text
    bad = CliRunner().invoke(app, ["synth", "--faults", "corupt_jpeg"])
    assert bad.exit_code == 2
    assert "corupt_jpeg" in bad.output and "corrupt_jpeg" in bad.output


def test_config_show_doc_is_the_same_yaml_with_descriptions(tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(TINY.format(out=tmp_path / "out"))
    plain, _ = m3gd(cfg, "config", "show")
    doc, _ = m3gd(cfg, "config", "show", "--doc")
    assert yaml.safe_load(doc) == yaml.safe_load(plain)
    field = M3GDConfig.model_fields["output_dir"]
    assert f"# {field.description}" in doc
    assert "# Euler steps K" in doc  # sample.steps


def test_accuracy_prints_progress_lines(tiny: tuple[Path, str, str]) -> None:
    cfg, _, _ = tiny
    _, err = m3gd(cfg, "accuracy")
    counts = [int(n) for n in re.findall(r"^accuracy views: (\d+), \d+ s$", err, re.M)]
    assert counts[0] == 0 and counts[-1] > 0, err
