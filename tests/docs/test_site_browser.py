"""The built documentation site in a real headless Chromium at 1280 px (Debian's chromium,
driven over the DevTools pipe as the report tests do): every page lays out inside its
column, tables scroll inside their box, every snippet is highlighted in its language, and no
link, image or stylesheet points at a file or anchor that does not exist."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlsplit

import pytest

from tests.pipeline.analysis.report.chromium import Browser, chromium_binary

REPO = Path(__file__).resolve().parents[2]
BINARY = chromium_binary()
pytestmark = pytest.mark.skipif(
    BINARY is None, reason="Debian's chromium is not installed (`make install` installs it: "
    "apt-get install chromium)")
WIDTH = 1280
TOKENIZED = {"python", "bash", "sh", "shell", "yaml", "json", "toml", "sql", "console", "py"}
"""Languages whose blocks must carry Pygments token spans (text blocks need not)."""

LAYOUT = """
(() => {
  const col = document.querySelector('.md-content');
  const box = col.getBoundingClientRect();
  const scrolls = el => { for (let a = el.parentElement; a && a !== col; a = a.parentElement) {
      const o = getComputedStyle(a).overflowX;
      if (o === 'auto' || o === 'scroll' || o === 'hidden') return true; }
    return false; };
  const wide = [...col.querySelectorAll('*')].filter(el => {
      const r = el.getBoundingClientRect();
      return r.width > 0 && r.right > box.right + 1 && !scrolls(el); })
    .map(el => el.tagName + '.' + el.className + ': ' + (el.textContent || '').slice(0, 40));
  const spills = [...col.querySelectorAll('table')].filter(t => {
      const wrap = t.closest('.md-typeset__scrollwrap') || t.parentElement;
      const o = getComputedStyle(wrap).overflowX;
      return wrap.getBoundingClientRect().right > box.right + 1
        || (t.scrollWidth > wrap.clientWidth + 1 && o !== 'auto' && o !== 'scroll'); })
    .map(t => t.textContent.slice(0, 40));
  const blocks = [...col.querySelectorAll('pre > code')].map(c => {
      const div = c.closest('.highlight');
      const cls = (div ? div.className : '') + ' ' + c.className;
      const lang = (cls.match(/language-([\\w-]+)/) || [])[1] || '';
      return [lang, c.querySelectorAll('span[class]').length, c.textContent.slice(0, 60)]; });
  const copy = [...col.querySelectorAll('pre')].filter(pre => {
      const btn = pre.querySelector('.md-clipboard');
      const code = pre.querySelector('code');
      if (!btn || !code) return false;
      const b = btn.getBoundingClientRect(), c = code.getBoundingClientRect();
      const pad = parseFloat(getComputedStyle(code).paddingRight);
      return b.left < c.right - pad; }).map(p => p.textContent.slice(0, 40));
  const broken = [...col.querySelectorAll('td, th')].flatMap(cell => {
    const out = [];
    const walk = document.createTreeWalker(cell, NodeFilter.SHOW_TEXT);
    for (let n = walk.nextNode(); n; n = walk.nextNode()) {
      const re = /[\\w.]+/g; let m;  // identifiers, keys, numbers (punctuation may end a line)
      while ((m = re.exec(n.data)) !== null) {
        const r = document.createRange();
        r.setStart(n, m.index); r.setEnd(n, m.index + m[0].length);
        if (new Set([...r.getClientRects()].map(q => Math.round(q.top))).size > 1)
          out.push(m[0]); } }
    return out; });
  const links = [...document.querySelectorAll('a[href], link[href], img[src], script[src]')]
    .map(e => e.href || e.src);
  const ids = [...document.querySelectorAll('[id]')].map(e => e.id);
  const remote = u => u.startsWith('http:') || u.startsWith('https:') || u.startsWith('//');
  const clipped = [...col.querySelectorAll('pre > code')]
    .filter(c => c.scrollWidth > c.clientWidth + 1).map(c => c.textContent.slice(0, 60));
  const scrolled = [...col.querySelectorAll('table')].filter(t => {
      const wrap = t.closest('.md-typeset__scrollwrap') || t.parentElement;
      return t.scrollWidth > wrap.clientWidth + 1; }).map(t => t.textContent.slice(0, 40));
  const fetched = [...document.querySelectorAll('link[href], script[src], img[src], iframe[src]')]
    .map(e => e.href || e.src).filter(remote);
  const remoteFonts = [...document.styleSheets].flatMap(sh => {
      try { return [...sh.cssRules]; } catch (e) { return []; } })
    .filter(r => r.type === CSSRule.FONT_FACE_RULE && r.cssText.includes('http'))
    .map(r => r.cssText.slice(0, 80));
  return {wide, spills, blocks, copy, links, ids, broken, clipped, scrolled, fetched, remoteFonts,
          page: [document.documentElement.scrollWidth, innerWidth]};
})()"""


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The site built from this checkout with --strict (as `make docs` does)."""
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "PYTHONPATH": str(REPO)}
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d",
                          str(out)], cwd=REPO, env=env, capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stderr
    return out


@pytest.fixture(scope="module")
def pages(site: Path) -> Iterator[dict[str, dict[str, Any]]]:
    """Each page's layout findings, links and anchors, read at WIDTH px."""
    assert BINARY is not None
    browser = Browser(BINARY)
    try:
        files = sorted(p for p in site.rglob("*.html") if "assets" not in p.parts)
        session = browser.page("about:blank", width=WIDTH)
        found = {}
        for f in files:
            browser.navigate(session, f.as_uri())
            found[str(f.relative_to(site))] = browser.evaluate(session, LAYOUT)
        yield found
    finally:
        browser.close()


def test_every_page_was_read(pages: dict[str, dict[str, Any]]) -> None:
    assert {"index.html", "getting_started.html", "troubleshooting.html", "changelog.html",
            "404.html", "reference/python_api.html", "guides/trainers.html"} <= set(pages)


def test_no_element_is_wider_than_its_column_nor_the_page(
        pages: dict[str, dict[str, Any]]) -> None:
    bad = {p: v["wide"][:3] for p, v in pages.items() if v["wide"]}
    assert bad == {}
    assert {p: v["page"] for p, v in pages.items() if v["page"][0] > v["page"][1]} == {}


def test_no_table_spills_out_of_its_box(pages: dict[str, dict[str, Any]]) -> None:
    assert {p: v["spills"] for p, v in pages.items() if v["spills"]} == {}


def test_every_snippet_is_highlighted_in_its_language(
        pages: dict[str, dict[str, Any]]) -> None:
    unnamed = {p: [b[2] for b in v["blocks"] if not b[0]] for p, v in pages.items()}
    assert {p: b for p, b in unnamed.items() if b} == {}
    plain = {p: [b[2] for b in v["blocks"] if b[0] in TOKENIZED and b[1] == 0]
             for p, v in pages.items()}
    assert {p: b for p, b in plain.items() if b} == {}
    python_as_shell = {p: [b[2] for b in v["blocks"] if b[0] in ("bash", "sh")
                           and "<<'EOF'" in b[2] and "python" in b[2]]
                       for p, v in pages.items()}
    assert {p: b for p, b in python_as_shell.items() if b} == {}
    assert sum(len(v["blocks"]) for v in pages.values()) > 50


def test_no_word_in_a_table_breaks_across_lines(pages: dict[str, dict[str, Any]]) -> None:
    """Config keys like `synth.scenes`, array names and numbers stay whole (a line may end at
    other punctuation: `/`, `-`, `=`)."""
    assert {p: v["broken"][:5] for p, v in pages.items() if v["broken"]} == {}


def test_the_copy_button_covers_no_code(pages: dict[str, dict[str, Any]]) -> None:
    assert {p: v["copy"] for p, v in pages.items() if v["copy"]} == {}


def test_no_link_is_broken(pages: dict[str, dict[str, Any]], site: Path) -> None:
    ids = {site / p: set(v["ids"]) for p, v in pages.items()}
    broken = []
    for page, found in pages.items():
        for url in found["links"]:
            parts = urlsplit(url)
            if parts.scheme != "file":
                continue  # external links are not followed
            target = Path(unquote(parts.path))
            if target.is_dir():
                broken.append(f"{page}: {url} (a folder: no page over file://)")
            elif not target.exists():
                broken.append(f"{page}: {url}")
            elif parts.fragment and target in ids and unquote(parts.fragment) not in ids[target]:
                broken.append(f"{page}: {url} (no such anchor)")
    assert broken == []
    assert any("404.html" in p for p in pages) and all(
        "file:///assets" not in u and "file:///index" not in u for u in pages["404.html"]["links"])


BAD_PAGE = """<html><body><div class="md-content" style="width:600px">
<pre style="overflow:visible"><code class="language-bash">{long}</code></pre>
<div class="md-typeset__scrollwrap" style="overflow:visible"><table><tr>{cells}</tr></table></div>
<div class="highlight"><pre><code>no language</code></pre></div>
<table style="width:3em"><tr><td style="overflow-wrap:anywhere">synth.scenes</td></tr></table>
<pre><code class="language-bash" style="display:block;white-space:pre;overflow-x:auto">
{long} y</code></pre>
<img src="https://fonts.invalid/x.png" alt="">
<a href="missing.html">x</a><a href="#nowhere">y</a></div></body></html>"""


def test_the_checks_catch_a_broken_page(tmp_path: Path) -> None:
    assert BINARY is not None
    page = tmp_path / "bad.html"
    page.write_text(BAD_PAGE.format(long="x" * 400, cells="<td>cell_value</td>" * 80))
    browser = Browser(BINARY)
    try:
        found = browser.evaluate(browser.page(page.as_uri(), width=WIDTH), LAYOUT)
    finally:
        browser.close()
    assert any(w.startswith("PRE") or w.startswith("CODE") for w in found["wide"])
    assert found["spills"]
    assert ["", 0, "no language"] in found["blocks"]
    assert found["blocks"][0][:2] == ["bash", 0]  # a shell block without token spans
    assert page.with_name("missing.html").as_uri() in found["links"]
    assert "nowhere" not in found["ids"]
    assert "synth.scenes" in found["broken"]
    assert any("xxx" in c for c in found["clipped"])
    assert found["fetched"] == ["https://fonts.invalid/x.png"]
    assert found["scrolled"]  # the 80-cell table needs its scroll bar


def test_no_page_requests_anything_beyond_the_site(pages: dict[str, dict[str, Any]]) -> None:
    """Was: every page asked a web-font server for its fonts (the site reads offline)."""
    assert {p: v["fetched"] + v["remoteFonts"] for p, v in pages.items()
            if v["fetched"] or v["remoteFonts"]} == {}


def test_code_wraps_instead_of_hiding_behind_a_scroll_bar(
        pages: dict[str, dict[str, Any]]) -> None:
    """Was: at 1280 px the end of long commands (their comments) was cut off."""
    assert {p: v["clipped"] for p, v in pages.items() if v["clipped"]} == {}


USER_PAGES = ("guides/", "reference/", "getting_started.html", "troubleshooting.html",
              "index.html", "architecture.html")
"""Pages a user reads to work: their tables fit the column at 1280 px (the measurement pages
may hold wider tables, which scroll inside their box)."""


def test_the_users_tables_fit_their_column_at_1280_px(pages: dict[str, dict[str, Any]]) -> None:
    users = {p: v["scrolled"] for p, v in pages.items() if p.startswith(USER_PAGES)}
    assert len(users) >= 8
    assert {p: t for p, t in users.items() if t} == {}
