"""Configuration files written whole (temp file, fsync, rename; a symlink written through), an
empty or comment-only file refused in one line, and synthesis only when asked for."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from schemas.config import (
    ConfigError,
    M3GDConfig,
    load_config,
    parse_config,
    synthetic_refusal,
    write_config_text,
)


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n# and another\n", "---\n"])
def test_an_empty_or_comment_only_file_is_refused_in_one_line(tmp_path: Path, text: str) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match="an empty configuration") as err:
        load_config(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_a_folder_or_binary_file_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="a folder"):
        load_config(tmp_path)
    (tmp_path / "b.yaml").write_bytes(b"\xff\xfe\x00bad")
    with pytest.raises(ConfigError, match="not a text file"):
        load_config(tmp_path / "b.yaml")


def test_the_file_is_replaced_whole(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("output_dir: old\n")
    (tmp_path / ".c.yaml.99999.tmp").write_text("output_di")  # a killed writer's temporary
    assert write_config_text(path, "output_dir: new\n") == path
    assert path.read_text() == "output_dir: new\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.yaml"]


def test_a_full_disk_keeps_the_previous_file(tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("output_dir: old\n")

    def full(fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError, match="No space left"):
        write_config_text(path, "output_dir: new\n")
    assert path.read_text() == "output_dir: old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.yaml"]


def test_a_symlink_is_written_through(tmp_path: Path) -> None:
    real = tmp_path / "shared" / "real.yaml"
    real.parent.mkdir()
    real.write_text("output_dir: old\n")
    link = tmp_path / "c.yaml"
    link.symlink_to(real)
    assert write_config_text(link, "output_dir: new\n") == real
    assert link.is_symlink() and real.read_text() == "output_dir: new\n"


def test_synthesis_only_when_asked_for(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("output_dir: out\n")
    omitted = load_config(path)
    refusal = synthetic_refusal(omitted)
    assert refusal is not None and "synthetic: true" in refusal and "\n" not in refusal
    assert synthetic_refusal(parse_config({"synthetic": True})) is None
    assert synthetic_refusal(parse_config({"ingest": {"recordings": [str(tmp_path)]}})) is None
    assert synthetic_refusal(parse_config({"synth": {"scenes": []}})) is None  # nothing made
    embedded = load_config(None)
    assert embedded.synthetic and synthetic_refusal(embedded) is None
    assert embedded == M3GDConfig(synthetic=True)
