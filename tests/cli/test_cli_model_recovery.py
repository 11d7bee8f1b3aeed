"""`m3gd train` / `eval` after a kill, on an unwritable output, and eval results inside
the cache: each either works in one command or is refused in one line (no traceback)."""

# ruff: noqa: F811  (the fixtures imported from test_cli_model are the arguments)
from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.app import app
from model.checkpoint import FILE, has_checkpoint, read_meta
from tests.cli.test_cli_model import checkpoint, out_dir  # noqa: F401  (a tiny trainable cache)

TEMP = f".{FILE}.4242.tmp"  # what a save killed mid-write leaves (pid 4242)


def _run(out: Path, *args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, ["-c", str(out / "m3gd.yaml"), *args])
    return result.exit_code, result.output


def _killed_first_save(folder: Path) -> Path:
    """A folder as a run killed during its first checkpoint write leaves it."""
    folder.mkdir(parents=True)
    (folder / TEMP).write_bytes(os.urandom(4096))
    return folder


def test_resume_of_a_killed_first_save_starts_over_saying_so(out_dir: Path,
                                                             tmp_path: Path) -> None:
    ck = _killed_first_save(tmp_path / "ck")
    code, text = _run(out_dir, "train", "--steps", "1", "--resume", "--out", str(ck))
    words = " ".join(text.split())
    assert code == 0, text
    assert "holds no checkpoint (its run stopped before the first save): starting over from " \
           "step 0" in words
    assert f"removed 1 temporary file(s) of killed checkpoint saves from {ck}" in words
    assert has_checkpoint(ck) and read_meta(ck)["step"] == 1 and not (ck / TEMP).exists()


@pytest.mark.parametrize("flags", [[], ["--force"]])
def test_train_into_a_killed_first_save_folder(out_dir: Path, tmp_path: Path,
                                               flags: list[str]) -> None:
    ck = _killed_first_save(tmp_path / "ck")
    code, text = _run(out_dir, "train", "--steps", "1", "--out", str(ck), *flags)
    assert code == 0, text
    assert has_checkpoint(ck)
    assert sorted(p.name for p in ck.iterdir()) == [FILE, "metrics.jsonl", "run.json"]


def test_temporaries_of_killed_saves_go_on_the_next_run(out_dir: Path, tmp_path: Path) -> None:
    ck = tmp_path / "ck"
    assert _run(out_dir, "train", "--steps", "1", "--out", str(ck))[0] == 0
    (ck / TEMP).write_bytes(b"x" * 100)
    code, text = _run(out_dir, "train", "--steps", "2", "--resume", "--out", str(ck))
    assert code == 0, text
    assert not (ck / TEMP).exists() and read_meta(ck)["step"] == 2


@pytest.fixture
def read_only_dir(tmp_path: Path) -> Iterator[Path]:
    """A folder the OS refuses writes into: a read-only tmpfs mount where this user may
    mount (root), else a folder without write permission."""
    folder = tmp_path / "ro"
    folder.mkdir()
    if os.geteuid() != 0:
        folder.chmod(0o555)
        yield folder
        folder.chmod(0o755)
        return
    if shutil.which("mount") is None or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(folder)],
            capture_output=True).returncode != 0:
        pytest.skip("root, and no read-only mount possible here (permissions do not bind root)")
    try:
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], check=True)


def test_train_on_a_read_only_output_is_one_line(out_dir: Path, read_only_dir: Path) -> None:
    code, text = _run(out_dir, "train", "--steps", "1", "--out", str(read_only_dir / "ck"))
    assert code == 1 and "Traceback" not in text, text
    line = " ".join(text.split())
    assert f"{read_only_dir / 'ck'}: checkpoints cannot be written there" in line
    assert "choose another --out" in line and len(text.strip().splitlines()) <= 2


def test_eval_result_inside_the_cache_is_refused(out_dir: Path, checkpoint: Path) -> None:
    inside = out_dir / "cache.zarr" / "eval.json"
    code, text = _run(out_dir, "eval", str(checkpoint), "--clips", "1", "--result", str(inside))
    assert code == 2 and "Traceback" not in text, text
    assert "inside the cache store" in " ".join(text.split())
    assert not inside.exists() and not inside.with_suffix(".parquet").exists()


def test_eval_result_over_a_foreign_file_is_refused(out_dir: Path, checkpoint: Path,
                                                    tmp_path: Path) -> None:
    notes = tmp_path / "notes.json"
    notes.write_text('{"mine": 1}')
    code, text = _run(out_dir, "eval", str(checkpoint), "--clips", "1", "--result", str(notes))
    assert code == 2 and "an existing file that m3gd did not write" in " ".join(text.split())
    assert notes.read_text() == '{"mine": 1}'


@pytest.mark.slow  # three tiny trainings, 10-20 s each on 2 shared cores
@pytest.mark.parametrize("flags", [[], ["--resume"], ["--force"]])
def test_a_first_save_killed_inside_the_safetensors_writer(out_dir: Path, tmp_path: Path,
                                                           flags: list[str]) -> None:
    """The writer's own `.tmpXXXXXX` (a kill inside `save_file`) is a killed save's
    temporary: removed, and the run goes on (was: every one of these refused the folder)."""
    ck = tmp_path / "ck"
    ck.mkdir()
    (ck / ".tmpQ7x2Lk").write_bytes(os.urandom(4096))
    code, text = _run(out_dir, "train", "--steps", "1", "--out", str(ck), *flags)
    assert code == 0, text
    assert sorted(p.name for p in ck.iterdir()) == [FILE, "metrics.jsonl", "run.json"]
