"""`m3gd report` (issue 20) in a real headless Chromium started by the test: the page loads with
no console error and no request beyond itself, every image decodes, the tables hold the numbers
of the Parquet files, and a screenshot is not blank."""

from __future__ import annotations

import base64
import io
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from PIL import Image

from pipeline.analysis.accuracy import run_accuracy
from pipeline.analysis.align import run_alignment, write_alignment
from pipeline.analysis.plots import plot_dtau_histograms
from pipeline.analysis.report.build import build_report
from pipeline.analysis.report.html import Section, figure, page
from schemas.config import M3GDConfig
from tests.pipeline.analysis.report.chromium import Browser, chromium_binary
from tests.pipeline.tiny_output import stats_rows, tiny_output

BINARY = chromium_binary()
pytestmark = pytest.mark.skipif(
    BINARY is None, reason="Debian's chromium is not installed (`make install` installs it: "
    "apt-get install chromium)")

ACCURACY = pa.table({"K": [1, 5, 10, 20], "M": [2, 2, 3, 4],
                     "psnr": [14.25, 17.5, 18.123456789, 18.3],
                     "latency_s": [0.0123, 0.061, 0.118, 0.2399]})
"""An extra table another stage could add under stats/ (the report lists it generically)."""


@pytest.fixture(scope="module")
def cfg(tmp_path_factory: pytest.TempPathFactory) -> M3GDConfig:
    cfg = tiny_output(tmp_path_factory)
    out = cfg.output_dir
    if not (out / "stats" / "alignment.parquet").exists():
        write_alignment(out, run_alignment(out, [("latents_l0", "h")], n_perm=3))
        run_accuracy(cfg)  # packet depth against the synthetic ground truth: stats/accuracy/
    pq.write_table(ACCURACY, out / "stats" / "latency.parquet")
    (out / "stats" / "tradeoff").mkdir(exist_ok=True)
    pq.write_table(ACCURACY.slice(0, 2), out / "stats" / "tradeoff" / "part-0.parquet")
    pq.write_table(ACCURACY.slice(2), out / "stats" / "tradeoff" / "part-1.parquet")
    return cfg


@pytest.fixture(scope="module")
def report(cfg: M3GDConfig) -> Path:
    return build_report(cfg.output_dir).path


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    assert BINARY is not None
    b = Browser(BINARY)
    try:
        yield b
    finally:
        b.close()


@pytest.fixture(scope="module")
def loaded(browser: Browser, report: Path) -> tuple[str, list[dict[str, Any]]]:
    """The report opened in a tab (session id) and the events seen while it loaded."""
    browser.events.clear()
    session = browser.page(report.as_uri())
    browser.evaluate(session, "new Promise(r => requestAnimationFrame(() => r(1)))")
    return session, list(browser.events)


def test_a_long_table_says_how_many_rows_it_left_out(browser: Browser,
                                                     loaded: tuple[str, list[dict[str, Any]]],
                                                     cfg: M3GDConfig) -> None:
    n = len(stats_rows(cfg, "accuracy"))
    text = browser.evaluate(loaded[0], "document.getElementById('table-accuracy').textContent")
    assert f"first 200 of {n} rows shown" in text


def _tables(browser: Browser, session: str) -> dict[str, list[list[str]]]:
    js = ("Object.fromEntries([...document.querySelectorAll('table')].map(t => [t.id, "
          "[...t.tBodies[0].rows].map(r => [...r.cells].map(c => c.textContent))]))")
    out: dict[str, list[list[str]]] = browser.evaluate(session, js)
    return out


def _num(text: str) -> float:
    return float(text) if text else float("nan")


def _errors(events: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Console errors and warnings, uncaught exceptions and browser log errors among events."""
    return [e for e in events if e.get("method") == "Runtime.exceptionThrown"
            or (e.get("method") == "Runtime.consoleAPICalled"
                and e["params"]["type"] in ("error", "assert", "warning"))
            or (e.get("method") == "Log.entryAdded"
                and e["params"]["entry"]["level"] in ("error", "warning"))]


def test_the_checks_catch_a_broken_page(browser: Browser, tmp_path: Path) -> None:
    bad = tmp_path / "bad.html"
    bad.write_text('<html><body><img alt="x" src="data:image/png;base64,AAAA">'
                   "<script>console.error('boom'); undefinedCall();</script></body></html>")
    browser.events.clear()
    session = browser.page(bad.as_uri())
    widths = browser.evaluate(session, "[...document.images].map(i => i.naturalWidth)")
    assert widths == [0]
    assert len(_errors(browser.events)) >= 2  # the console.error and the ReferenceError


def test_page_loads_with_no_console_error_and_no_request_beyond_itself(
        loaded: tuple[str, list[dict[str, Any]]], report: Path) -> None:
    _, events = loaded
    assert _errors(events) == []
    urls = [e["params"]["request"]["url"] for e in events
            if e.get("method") == "Network.requestWillBeSent"]
    assert report.as_uri() in urls
    assert all(u == report.as_uri() or u.startswith("data:") for u in urls), urls


def test_every_image_decodes(browser: Browser, loaded: tuple[str, list[dict[str, Any]]],
                             cfg: M3GDConfig) -> None:
    session, _ = loaded
    imgs = browser.evaluate(session, "Promise.all([...document.images].map(i => i.decode()"
                            ".then(() => [i.naturalWidth, i.naturalHeight, i.dataset.file])))")
    pngs = sorted(p.stem for p in (cfg.output_dir / "plots").glob("*.png"))
    assert sorted(alt for _, _, alt in imgs) == pngs and len(pngs) >= 4
    for (w, h, alt) in imgs:
        png = Image.open(cfg.output_dir / "plots" / f"{alt}.png")
        assert (w, h) == png.size and w > 0


ZOOM = """(() => {
  const fig = [...document.querySelectorAll('figure[id]')].find(f => {
    const i = f.querySelector('img');
    return i.naturalWidth > i.getBoundingClientRect().width + 5; });  // shown smaller than drawn
  if (!fig) return null;
  const img = fig.querySelector('img');
  const before = img.getBoundingClientRect().width;
  location.hash = fig.id;
  const after = img.getBoundingClientRect().width, box = fig.getBoundingClientRect();
  const closed = getComputedStyle(fig.querySelector('a.close')).display;
  location.hash = 'plots';
  return [before, after, img.naturalWidth, box.width, innerWidth, closed,
          img.getBoundingClientRect().width];
})()"""


def test_a_click_on_a_plot_shows_it_at_its_drawn_size(
        browser: Browser, loaded: tuple[str, list[dict[str, Any]]]) -> None:
    session, _ = loaded
    _at_width(browser, session, 1280)
    found = browser.evaluate(session, ZOOM)
    assert found is not None, "no plot is shown smaller than drawn at 1280 px"
    before, after, natural, box, inner, close, back = found
    assert after == pytest.approx(natural, abs=3) and before < natural  # drawn size (+ border)
    assert box == pytest.approx(inner, abs=20) and close == "block"  # over the page, closable
    assert back == pytest.approx(before, abs=1)  # closed: fitted to the page again


def test_plots_wider_than_half_the_page_take_its_width(
        browser: Browser, loaded: tuple[str, list[dict[str, Any]]]) -> None:
    session, _ = loaded
    _at_width(browser, session, 1280)
    shown = browser.evaluate(session, "[...document.images].map(i => "
                             "[i.naturalWidth, i.getBoundingClientRect().width])")
    wide = [(n, w) for n, w in shown if n > 600]
    assert wide and all(w >= min(n, 1100) for n, w in wide)


def test_tables_hold_the_numbers_of_the_parquet_files(
        browser: Browser, loaded: tuple[str, list[dict[str, Any]]], cfg: M3GDConfig) -> None:
    t = _tables(browser, loaded[0])
    out = cfg.output_dir
    align = pq.read_table(out / "stats" / "alignment.parquet").to_pylist()
    assert len(t["t-alignment"]) == len(align) > 0
    for row, want in zip(t["t-alignment"], align, strict=True):
        assert row[:2] == [want["pair"], want["metric"]]
        got = [_num(x) for x in row[2:5]]
        expect = [want["value"], want["null_value"], want["value"] - want["null_value"]]
        np.testing.assert_allclose(got, expect, rtol=1e-5, atol=1e-12)
        assert [int(x) for x in row[5:]] == [want["images"], want["excluded_images"]]
    for name in ("t-latency", "t-tradeoff"):
        shown = np.array([[_num(x) for x in r] for r in t[name]])
        want = np.array([list(r.values()) for r in ACCURACY.to_pylist()], np.float64)
        np.testing.assert_allclose(shown, want, rtol=5e-6)  # 6 significant digits
    accuracy = stats_rows(cfg, "accuracy")  # a real table, longer than the 200 rows listed
    assert len(t["t-accuracy"]) == 200 < len(accuracy)
    for row, want in zip(t["t-accuracy"], accuracy, strict=False):
        assert row[:3] == [want["recording"], want["camera"], str(want["frame"])]
        np.testing.assert_allclose(_num(row[6]), want["depth_m"], rtol=5e-6)
    _check_dtau(t["t-dtau"], stats_rows(cfg, "view_stats"))
    _check_occupancy(t["t-occupancy"], stats_rows(cfg, "view_stats"))
    rejects = pq.read_table(out / "index" / "t_view" / "rejects.parquet").to_pylist()
    counts: dict[tuple[str, str], int] = {}
    for r in rejects:
        counts[(r["topic"], r["reason"])] = counts.get((r["topic"], r["reason"]), 0) + 1
    assert {(r[1], r[2]): int(r[3]) for r in t["t-rejects"]} == counts and counts
    checks = pq.read_table(out / "index" / "t_view" / "checks.parquet").to_pylist()
    assert [(r[1], r[2], r[3], int(r[7])) for r in t["t-checks"]] == [
        (c["topic"], c["check"], c["state"], c["trusted"]) for c in checks] and checks
    images = pq.read_metadata(out / "index" / "t_view" / "images.parquet").num_rows
    assert t["t-recordings"] == [["t_view", str(images), str(pq.read_metadata(
        out / "index" / "t_view" / "sweeps.parquet").num_rows), *t["t-recordings"][0][3:]]]


def _check_dtau(rows: list[list[str]], views: list[dict[str, Any]]) -> None:
    """Δτ rows (recording, camera, views, rejected, then over accepted views mean, median |.|,
    p95 |.|, max |.|, and max |.| of the rejected, in ms)."""
    assert len(rows) == 3
    for row in rows:
        mine = [v for v in views if v["camera"] == row[1]]
        ok = np.array([v["dtau_s"] for v in mine if v["reject_reason"] is None]) * 1e3
        bad = np.array([v["dtau_s"] for v in mine if v["reject_reason"] is not None]) * 1e3
        assert int(row[2]) == len(mine)
        assert int(row[3]) == bad.size > 0
        expect = [ok.mean(), np.median(np.abs(ok)), np.percentile(np.abs(ok), 95),
                  np.abs(ok).max(), np.abs(bad).max()]
        np.testing.assert_allclose([_num(x) for x in row[4:9]], expect, atol=6e-4)


def _check_occupancy(rows: list[list[str]], views: list[dict[str, Any]]) -> None:
    """Occupancy rows (recording, camera, views, mean / min / max supported cells, mean points
    in frustum, sparse views) over accepted views."""
    for row in rows:
        ok = [v for v in views if v["camera"] == row[1] and v["reject_reason"] is None]
        cells = np.array([v["supported_cells"] for v in ok])
        pts = np.array([v["points_in_frustum"] for v in ok])
        assert int(row[2]) == len(ok) > 0
        assert _num(row[3]) == pytest.approx(cells.mean(), abs=6e-4)
        assert [int(row[4]), int(row[5])] == [cells.min(), cells.max()]
        assert _num(row[6]) == pytest.approx(pts.mean(), abs=0.06)
        assert int(row[7]) == int((cells < 3).sum())


def test_screenshot_is_not_blank(browser: Browser, loaded: tuple[str, list[dict[str, Any]]],
                                 tmp_path: Path) -> None:
    session, _ = loaded
    browser.send("Emulation.setDeviceMetricsOverride", {"width": 1280, "height": 2000,
                                                        "deviceScaleFactor": 1, "mobile": False},
                 session=session)
    data = browser.send("Page.captureScreenshot", {"format": "png"}, session=session)["data"]
    shot = np.asarray(Image.open(io.BytesIO(base64.b64decode(data))).convert("RGB"))
    (tmp_path / "report.png").write_bytes(base64.b64decode(data))  # kept for a look by hand
    assert shot.shape[:2] == (2000, 1280)
    ink = (shot < 200).any(axis=2)  # text, table lines, plot pixels
    assert 0.01 < ink.mean() < 0.9
    assert len(np.unique(shot.reshape(-1, 3), axis=0)) > 50  # not one flat colour


def test_report_json_free_of_server_or_script(report: Path) -> None:
    text = report.read_text()
    assert "<script" not in text and "http://" not in text and "https://" not in text
    assert json.dumps("default-src 'none'")[1:-1] in text


def _at_width(browser: Browser, session: str, width: int) -> None:
    browser.send("Emulation.setDeviceMetricsOverride", {"width": width, "height": 900,
                                                        "deviceScaleFactor": 1, "mobile": False},
                 session=session)  # reading scrollWidth below lays the page out again


def test_no_horizontal_overflow_at_1280_px(browser: Browser,
                                           loaded: tuple[str, list[dict[str, Any]]]) -> None:
    session, _ = loaded
    _at_width(browser, session, 1280)
    page = browser.evaluate(session, "[document.documentElement.scrollWidth, "
                            "document.documentElement.clientWidth]")
    assert page[0] <= page[1], page
    wide = browser.evaluate(session, "[...document.querySelectorAll('table')].filter(t => "
                            "t.getBoundingClientRect().width > t.parentElement.clientWidth + 1)"
                            ".map(t => t.id)")
    assert wide == []  # not one table scrolls inside its box either (the Δτ table included)


def test_the_check_sees_an_overflowing_page(browser: Browser, tmp_path: Path) -> None:
    bad = tmp_path / "wide.html"
    bad.write_text('<html><body><table id="w"><tr><td style="min-width:2000px">x</td></tr>'
                   "</table></body></html>")
    session = browser.page(bad.as_uri())
    _at_width(browser, session, 1280)
    assert browser.evaluate(session, "document.documentElement.scrollWidth > "
                            "document.documentElement.clientWidth")


def test_summaries_come_before_raw_rows(browser: Browser,
                                        loaded: tuple[str, list[dict[str, Any]]]) -> None:
    ids = browser.evaluate(loaded[0], "[...document.querySelectorAll('section')].map(s => s.id)")
    assert ids.index("accuracy") < ids.index("table-accuracy")
    assert max(ids.index(s) for s in ("summary", "rejects", "dtau", "alignment", "accuracy",
                                      "plots")) < min(i for i, s in enumerate(ids)
                                                      if s.startswith("table-"))
    rows = _tables(browser, loaded[0])["t-accuracy-summary"]
    keys = {r[0] for r in rows}
    assert {"depth_abs_rel", "depth_rmse_m", "cells"} <= keys


def test_plots_have_captions_not_file_names(browser: Browser,
                                            loaded: tuple[str, list[dict[str, Any]]]) -> None:
    figs = browser.evaluate(loaded[0], "[...document.querySelectorAll('figure')].map(f => "
                            "[f.querySelector('img').dataset.file, "
                            "f.querySelector('figcaption').textContent])")
    assert len(figs) >= 4
    for name, caption in figs:
        assert caption != name and " " in caption, (name, caption)


def test_only_stages_are_listed(browser: Browser,
                                loaded: tuple[str, list[dict[str, Any]]]) -> None:
    from dags.graph import stage_names

    stages = [r[0] for r in _tables(browser, loaded[0])["t-stages"]]
    assert stages and set(stages) <= set(stage_names())


WIDTH = 1280
"""Viewport width (CSS px) of the layout checks."""
MAX_HEIGHT_PX = 8000
"""Goal for the report page's height at WIDTH (the demo's report measured 4,893 px)."""

MID_WORD_BREAKS = """
[...document.querySelectorAll('th')].flatMap(th => {
  const out = [];
  const walk = document.createTreeWalker(th, NodeFilter.SHOW_TEXT);
  for (let n = walk.nextNode(); n; n = walk.nextNode()) {
    const re = /\\S+/g; let m;
    while ((m = re.exec(n.data)) !== null) {
      const r = document.createRange();
      r.setStart(n, m.index); r.setEnd(n, m.index + m[0].length);
      const lines = new Set([...r.getClientRects()].map(q => Math.round(q.top)));
      if (lines.size > 1) out.push(th.textContent + ' / ' + m[0]);
    }
  }
  return out;
})"""
"""Header words (text between spaces and <wbr> breaks) laid out on more than one line."""


@pytest.fixture(scope="module")
def wide(browser: Browser, report: Path) -> str:
    """The report in a tab WIDTH px wide (session id)."""
    return browser.page(report.as_uri(), width=WIDTH)


def test_no_header_breaks_mid_word(browser: Browser, wide: str, tmp_path: Path) -> None:
    assert browser.evaluate(wide, MID_WORD_BREAKS) == []
    narrow = tmp_path / "narrow.html"  # the check finds a word broken inside a narrow box
    narrow.write_text('<table><tr><th style="width:2em;overflow-wrap:anywhere">camera_'
                      "identifier</th></tr></table>")
    session = browser.page(narrow.as_uri(), width=WIDTH)
    assert browser.evaluate(session, MID_WORD_BREAKS) != []


def test_raw_tables_are_collapsed_and_summaries_come_first(browser: Browser, wide: str) -> None:
    raw = browser.evaluate(wide, "[...document.querySelectorAll('section[id^=table-]')].map("
                           "s => [s.id, !!s.querySelector('details:not([open]) table'), "
                           "s.querySelector('table').checkVisibility() ? 1 : 0])")
    assert {r[0] for r in raw} >= {"table-accuracy", "table-latency", "table-tradeoff"}
    assert all(collapsed and height == 0 for _, collapsed, height in raw), raw
    order = browser.evaluate(wide, "[...document.querySelectorAll('section')].map(s => s.id)")
    assert order.index("plots") < min(order.index(r[0]) for r in raw)
    assert order[:4] == ["summary", "geometry", "rejects", "dtau"]  # the verdict up front


def test_page_height_and_width_fit(browser: Browser, wide: str) -> None:
    height, width = browser.evaluate(wide, "[document.documentElement.scrollHeight, "
                                     "document.documentElement.scrollWidth]")
    assert height <= MAX_HEIGHT_PX and width <= WIDTH


def test_stages_are_in_pipeline_order(browser: Browser, wide: str) -> None:
    stages = [r[0] for r in _tables(browser, wide)["t-stages"]]
    from pipeline.analysis.report.sections import PIPELINE_ORDER

    assert stages == [s for s in PIPELINE_ORDER if s in stages] and len(stages) >= 5


def test_a_ten_camera_dtau_grid_is_shown_at_a_readable_scale(browser: Browser,
                                                              tmp_path: Path) -> None:
    """Was: a ten-camera robot's Δτ grid (a 1200 px image) was shown at 581 px, its panel
    titles about 5 px high. Now it takes the page's width (titles drawn at 9 pt, 12.5 px, stay
    at 11 px or more) and a click shows it at its drawn size."""
    rng = np.random.default_rng(0)
    cams = [f"cam_{k}" for k in range(10)]
    views = pa.table({"recording": ["robot_a"] * 400, "camera": [cams[k % 10] for k in range(400)],
                      "dtau_s": rng.normal(0.0, 0.02, 400)})
    png = plot_dtau_histograms(views, tmp_path / "dtau_hist.png").read_bytes()
    doc = page("ten cameras", [Section("plots", "Plots", figure(png, "Δτ", "dtau_hist"))])
    (tmp_path / "r.html").write_text(doc)
    session = browser.page((tmp_path / "r.html").as_uri(), width=1280)
    natural, shown = browser.evaluate(session, "[document.images[0].naturalWidth, "
                                      "document.images[0].getBoundingClientRect().width]")
    assert natural == 1200  # three panels of 400 px a row
    title_px = 9 / 72 * 100 * shown / natural
    assert shown >= 1100 and title_px >= 11
