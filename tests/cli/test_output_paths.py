"""Outputs m3gd refuses to write, each in one line: inside the cache store, over a file or
folder m3gd did not write; and torch thread counts beyond what the machine can run."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.app import app
from cli.common import checkpoint_folder, max_threads, rerun_file


def _cfg(tmp_path: Path) -> Path:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {tmp_path / 'out'}\n")
    (tmp_path / "out" / "cache.zarr").mkdir(parents=True, exist_ok=True)
    return cfg


def _refused(args: list[str], tmp_path: Path) -> tuple[int, str]:
    """(exit code, output joined into one line) of `m3gd -c <cfg> *args`."""
    result = CliRunner().invoke(app, ["-c", str(_cfg(tmp_path)), *args])
    return result.exit_code, result.output.replace("\n", "")


def test_train_out_an_existing_file(tmp_path: Path) -> None:
    """Was: a FileExistsError traceback."""
    (tmp_path / "afile").write_text("x")
    code, out = _refused(["train", "--steps", "1", "--out", str(tmp_path / "afile")], tmp_path)
    assert code == 2 and "Traceback" not in out, out
    assert "afile: an existing file that m3gd did not write" in out


def test_train_out_inside_the_cache(tmp_path: Path) -> None:
    code, out = _refused(["train", "--steps", "1", "--out",
                          str(tmp_path / "out" / "cache.zarr" / "ck")], tmp_path)
    assert code == 2 and "Traceback" not in out, out
    assert "inside the cache store" in out


def test_view_out_inside_the_cache_or_over_a_foreign_file(tmp_path: Path) -> None:
    code, out = _refused(["view", "-o", str(tmp_path / "out" / "cache.zarr" / "v.rrd")],
                         tmp_path)
    assert code == 2 and "Traceback" not in out, out
    assert "inside the cache store" in out
    (tmp_path / "notes.rrd").write_text("my notes")
    code, out = _refused(["view", "-o", str(tmp_path / "notes.rrd")], tmp_path)
    assert code == 2 and "Traceback" not in out, out
    assert "an existing file that m3gd did not write" in out
    assert (tmp_path / "notes.rrd").read_text() == "my notes"  # left as it was


def test_train_threads_beyond_the_machine(tmp_path: Path) -> None:
    """Was: --threads 100000 crashed (SIGSEGV) inside OpenMP."""
    code, out = _refused(["train", "--steps", "1", "--threads", "100000"], tmp_path)
    assert code == 2 and "Traceback" not in out, out
    assert "--threads 100000: more than" in out


@pytest.mark.parametrize(("cpus", "most"), [(1, 64), (16, 64), (17, 68), (64, 256)])
def test_max_threads(cpus: int, most: int) -> None:
    assert max_threads(cpus) == most


def test_what_counts_as_ours(tmp_path: Path) -> None:
    assert checkpoint_folder(tmp_path)  # empty
    (tmp_path / "state.json").write_text("{}")
    assert checkpoint_folder(tmp_path)  # a checkpoint of the earlier format
    single = tmp_path / "single"
    single.mkdir()
    (single / "checkpoint.safetensors").write_bytes(b"")
    assert checkpoint_folder(single)
    other = tmp_path / "other"
    other.mkdir()
    (other / "thesis.tex").write_text("x")
    assert not checkpoint_folder(other) and not checkpoint_folder(other / "thesis.tex")
    (tmp_path / "a.rrd").write_bytes(b"RRF2" + b"\0" * 8)
    (tmp_path / "b.rrd").write_bytes(b"PK")
    assert rerun_file(tmp_path / "a.rrd") and not rerun_file(tmp_path / "b.rrd")


def test_a_lock_that_cannot_be_released_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    """Was: ~130 traceback lines raised while releasing the lock of a store killed mid-run."""
    from cli.stages import release_lock
    from store.object_store import StorageError

    class Gone:
        def release(self) -> None:
            raise StorageError("s3://b/out/.m3gd.lock (endpoint http://x): connection refused")

    release_lock(Gone(), Path("s3://b/out"))
    err = capsys.readouterr().err
    assert "could not release the lock of s3://b/out" in err and "m3gd unlock" in err


def test_an_error_from_a_loader_worker_is_one_line() -> None:
    """Was: a CorruptChunkError raised in a DataLoader worker printed the worker's traceback."""
    from cli.common import one_line

    wrapped = ("Caught CorruptChunkError in DataLoader worker process 0.\nOriginal Traceback "
               "(most recent call last):\n  File \"x.py\", line 1, in f\n    raise E\n"
               "store.shard_reader.CorruptChunkError: /c/0/0/0/0 view 4: CRC32C mismatch\n")
    assert one_line(wrapped) == "/c/0/0/0/0 view 4: CRC32C mismatch"
    assert one_line("plain: message") == "plain: message"
