"""Report building blocks and the report of a bare folder (no browser needed)."""

from __future__ import annotations

import base64
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.analysis.report.build import build_report
from pipeline.analysis.report.html import (
    cell_text,
    figure,
    page,
    png_data_uri,
    png_width,
    table_html,
)
from pipeline.analysis.report.sections import extra_tables


def test_cell_text_formats_numbers_and_blanks() -> None:
    assert [cell_text(v) for v in (3, 2.0, 18.123456789, 1e-9, None, float("nan"), True,
                                   [1, 2.5])] == ["3", "2", "18.1235", "1e-09", "", "", "true",
                                                  "1, 2.5"]


def test_tables_escape_text_and_say_what_they_left_out() -> None:
    t = pa.table({"name": ["<b>&"], "x": [1.5]})
    out = table_html(t, "t-x", "cap", total_rows=10)
    assert "&lt;b&gt;&amp;" in out and "<b>&" not in out
    assert 'id="t-x"' in out and "first 1 of 10 rows shown" in out
    assert "none" in table_html(t.slice(0, 0), "t-e")


def test_images_are_data_uris_and_the_page_forbids_fetches() -> None:
    png = b"\x89PNG\r\n\x1a\nxyz"
    uri = png_data_uri(png)
    assert base64.b64decode(uri.removeprefix("data:image/png;base64,")) == png
    assert uri in figure(png, "p")
    html = page("t", [])
    assert "default-src 'none'" in html and "<script" not in html


def test_extra_tables_skip_the_ones_with_their_own_section(tmp_path: Path) -> None:
    stats = tmp_path / "stats"
    for rel in ("view_stats/recording=r/a.parquet", "parts/r/x.parquet", "alignment.parquet",
                "accuracy.parquet", "curve/p0.parquet", "curve/p1.parquet"):
        (stats / rel).parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.table({"v": [1, 2, 3]}), stats / rel)
    found = extra_tables(tmp_path, max_rows=4)
    assert [s.id for s in found] == ["table-accuracy", "table-curve"]
    assert "first 4 of 6 rows shown" in found[1].body


def test_report_of_a_bare_folder_says_what_is_missing(tmp_path: Path) -> None:
    result = build_report(tmp_path, plots=False)
    text = result.path.read_text()
    assert result.path == tmp_path / "report.html" and result.bytes == len(text.encode())
    for msg in ("no manifest.json", "no rejects table", "no view statistics yet",
                "no alignment table", "no plots"):
        assert msg in text
    with pytest.raises(FileNotFoundError, match="no output directory"):
        build_report(tmp_path / "nope")


def test_report_of_an_output_still_being_written_says_so(tmp_path: Path) -> None:
    """Was: the report of a running output never said it was incomplete."""
    from pipeline.run.lock import OutputLock

    with OutputLock(tmp_path):  # this process is the running run
        result = build_report(tmp_path, plots=False)
    assert result.sections[0] == "incomplete"
    assert any("still being written" in m for m in result.messages)
    assert "Incomplete: a run is still writing this output" in result.path.read_text()
    again = build_report(tmp_path, plots=False)  # the run ended: the lock file is gone
    assert "incomplete" not in again.sections


def test_a_killed_runs_lock_file_is_not_a_running_run(tmp_path: Path) -> None:
    import json
    import socket
    import subprocess
    import sys

    from pipeline.run.lock import LOCK_NAME, running_holder

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    (tmp_path / LOCK_NAME).write_text(json.dumps(
        {"host": socket.gethostname(), "pid": int(dead.stdout), "started_unix_s": 0.0}))
    assert running_holder(tmp_path) is None
    (tmp_path / LOCK_NAME).write_text(json.dumps(
        {"host": "elsewhere", "pid": 1, "started_unix_s": 0.0}))
    assert running_holder(tmp_path) is not None  # another host: cannot tell, said so


def test_an_empty_table_is_one_sentence_not_a_table_then_none() -> None:
    empty = table_html(pa.table({"x": pa.array([], pa.int64())}), "t-e", "dropped messages")
    assert empty == '<p class="note">dropped messages: none</p>'


def test_headers_break_only_between_words() -> None:
    html = page("t", [])
    th_rule = html.split("th{", 1)[1].split("}", 1)[0]
    assert "overflow-wrap:normal" in th_rule and "word-break:normal" in th_rule
    assert "th{overflow-wrap:anywhere" not in html and "th.s{overflow-wrap" not in html
    assert "max_<wbr>abs" in table_html(pa.table({"max_abs": [1]}), "t")


def test_long_text_cells_wrap_anywhere() -> None:
    assert "td.s{overflow-wrap:anywhere}" in page("t", [])


def test_raw_rows_are_collapsed(tmp_path: Path) -> None:
    (tmp_path / "stats").mkdir()
    pq.write_table(pa.table({"v": [1, 2, 3]}), tmp_path / "stats" / "curve.parquet")
    (section,) = extra_tables(tmp_path, max_rows=2)
    assert section.body.startswith("<details><summary>raw rows of stats/curve (first 2 of 3 "
                                   "rows)</summary>")


def test_stages_are_listed_in_pipeline_order() -> None:
    from dags.graph import stage_names
    from pipeline.analysis.report.sections import PIPELINE_ORDER

    assert list(PIPELINE_ORDER) == stage_names()


def test_every_plot_is_captioned_in_words() -> None:
    from pipeline.analysis.report.sections import plot_caption

    assert plot_caption("train_full").startswith("Training run full: loss")
    assert plot_caption("pca_rec_cam_00002") == ("Image, latent PCA and point-feature PCA of "
                                                 "rec_cam frame 2")
    assert plot_caption("new_kind") == "Plot new kind"


def _png_header(width: int, height: int) -> bytes:
    size = width.to_bytes(4, "big") + height.to_bytes(4, "big")
    return b"\x89PNG\r\n\x1a\n" + b"\0\0\0\rIHDR" + size


def test_a_plot_wider_than_half_the_page_takes_the_row_and_every_plot_enlarges() -> None:
    assert png_width(_png_header(1200, 900)) == 1200 and png_width(b"not a png") == 0
    wide, half = figure(_png_header(1200, 900), "grid", "dtau"), figure(_png_header(600, 400), "h")
    assert '<figure id="fig-dtau" class="wide">' in wide
    assert 'class="wide"' not in half  # 600 px: exactly half the page, not wider
    assert '<a class="zoom" href="#fig-dtau">' in wide and 'href="#plots">close</a>' in wide
    assert figure(_png_header(600, 400), "h") == half  # an unnamed figure's anchor is stable
