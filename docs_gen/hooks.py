"""MkDocs hooks (`hooks:` in mkdocs.yml): the reference pages, generated from the code at
build time, and nav entries of optional pages dropped when their file is absent."""

from __future__ import annotations

import logging
import re
import sys
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's code first
from docs_gen import cache_ref, cli_ref, config_ref, conventions_ref, tables_ref

log = logging.getLogger("mkdocs.hooks.docs_gen")

GENERATED = {
    "reference/configuration.md": config_ref.render,
    "reference/tables.md": tables_ref.render,
    "reference/cache.md": cache_ref.render,
    "reference/cli.md": cli_ref.render,
    "reference/conventions.md": conventions_ref.render,
}
"""Site path -> function returning the page's Markdown."""

OPTIONAL = {"training_gpus.md", "testing.md", "benchmarks_science.md"}
"""Pages written alongside the code that may not exist yet: listed in the nav, dropped from it
(with an info line) while absent, so `--strict` stays green."""


def _prune(nav: list[Any], docs_dir: Path) -> list[Any]:
    out = []
    for entry in nav:
        if isinstance(entry, dict):
            (title, value), = entry.items()
            if isinstance(value, list):
                out.append({title: _prune(value, docs_dir)})
                continue
            if value in OPTIONAL and not (docs_dir / value).exists():
                log.info("nav: %s is not written yet; left out", value)
                continue
        out.append(entry)
    return out


def on_config(config: Any) -> Any:
    """Drop absent optional pages from the nav."""
    config["nav"] = _prune(config["nav"], Path(config["docs_dir"]))
    return config


def on_files(files: Files, config: Any) -> Files:
    """Add the generated reference pages."""
    for path, render in GENERATED.items():
        files.append(File.generated(config, path, content=render()))
    return files


def _absent(config: Any) -> set[str]:
    return {p for p in OPTIONAL if not (Path(config["docs_dir"]) / p).exists()}


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files) -> str:
    """A link to an absent optional page becomes its text and the page's path."""
    for name in _absent(config):
        pattern = re.compile(r"\[([^\]]+)\]\((?:\.\./)*" + re.escape(name) + r"(#[^)]*)?\)")
        markdown = pattern.sub(lambda m, n=name: f"{m.group(1)} (`docs/{n}`)", markdown)
    return markdown


_ROOT_LINK = re.compile(r'(\s(?:href|src|action)=")/(?!/)')


def relative_root_links(html: str) -> str:
    """Root-absolute links (`href="/x"`) of a page at the site's root made relative
    (`href="./x"`), so the page also works over file:// and below a sub-path."""
    return _ROOT_LINK.sub(r"\1./", html)


def on_post_template(output_content: str, template_name: str, config: Any) -> str:
    """404.html: MkDocs writes it with root-absolute links (it may be served at any path);
    the site is read from a folder or below a sub-path, so they become relative."""
    if template_name == "404.html":
        return relative_root_links(output_content)
    return output_content
