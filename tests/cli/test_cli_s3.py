"""`m3gd stats query` over an output on S3 (a moto server), and storage errors as one line
naming the URL with exit code 1: wrong endpoint, missing bucket, refused credentials."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bench.support.local_s3 import LocalS3, free_port, local_s3
from cli.app import app
from pipeline.stats.merge import merge_recording
from tests.cli.test_cli_model import out_dir  # noqa: F401  (a tiny trainable cache)
from tests.pipeline.stats.test_stats import _write_shards
from tests.s3_fixture import upload

SQL = "SELECT frame, reject_reason FROM view_stats ORDER BY frame"


def _run(tmp_path: Path, url: str, *args: str) -> tuple[int, str]:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {url}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "stats", "query", *args])
    return result.exit_code, result.output


def _one_line_error(code: int, output: str, url: str, secret: str) -> str:
    assert code == 1, output
    text = output.strip()
    assert len(text.splitlines()) == 1 and "Traceback" not in text, text
    assert url in text and secret not in text
    return text


def test_query_on_s3(tmp_path: Path, s3: str) -> None:
    _write_shards(tmp_path / "out")
    merge_recording(tmp_path / "out", "rec")
    upload(tmp_path / "out", s3)
    code, out = _run(tmp_path, s3, SQL, "--json")
    assert code == 0, out
    assert [json.loads(line)["frame"] for line in out.splitlines()] == [0, 1, 2]


def test_missing_bucket(tmp_path: Path, s3: str, monkeypatch: pytest.MonkeyPatch) -> None:
    url = "s3://m3gd-no-such-bucket/out"
    text = _one_line_error(*_run(tmp_path, url, SQL), url, "m3gd-secret")
    assert "no such bucket" in text


def test_wrong_endpoint(tmp_path: Path, s3: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{free_port()}")
    text = _one_line_error(*_run(tmp_path, s3, SQL), s3, "m3gd-secret")
    assert "cannot connect" in text


@pytest.fixture(scope="module")
def strict_s3(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LocalS3]:
    """A second server that checks signatures against its IAM (knows no key at all)."""
    pytest.importorskip("moto.server")
    with local_s3(tmp_path_factory.mktemp("strict") / "log", enforce_auth=True) as server:
        yield server


def test_refused_credentials(tmp_path: Path, strict_s3: LocalS3,
                             monkeypatch: pytest.MonkeyPatch) -> None:
    for key, value in strict_s3.env.items():
        monkeypatch.setenv(key, value)
    url = "s3://m3gd-test-strict/out"
    text = _one_line_error(*_run(tmp_path, url, SQL), url, strict_s3.env["AWS_SECRET_ACCESS_KEY"])
    assert "access denied" in text


def test_train_refuses_checkpoints_on_s3(tmp_path: Path, s3: str) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {s3}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "train", "--steps", "1"])
    text = _one_line_error(result.exit_code, result.output, s3, "m3gd-secret")
    assert "--out" in text and not (tmp_path / "s3:").exists() and not Path("s3:").exists()


def test_train_from_s3_equals_local(tmp_path: Path, s3: str, out_dir: Path,  # noqa: F811
                                    monkeypatch: pytest.MonkeyPatch) -> None:
    upload(out_dir, s3)
    monkeypatch.setenv("M3GD_SHARD_CACHE", str(tmp_path / "mirror"))
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {s3}\ntrain: {{batch_size: 4, lr: 0.001}}\n")
    for config, ck in ((cfg, "s3"), (out_dir / "m3gd.yaml", "local")):
        result = CliRunner().invoke(app, ["-c", str(config), "train", "--steps", "2",
                                          "--out", str(tmp_path / ck)])
        assert result.exit_code == 0, result.output
    same = [(tmp_path / "s3" / f).read_bytes() == (tmp_path / "local" / f).read_bytes()
            for f in ("checkpoint.safetensors",)]
    assert all(same)  # the same clips in the same order: the same weights
    assert any((tmp_path / "mirror").rglob("c/*"))  # shard objects came through the mirror


def _run_on(tmp_path: Path, url: str) -> tuple[int, str]:
    """`m3gd run --local` with the output at `url` (run from `tmp_path`)."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {url}\nsynthetic: true\n")  # synthesized recordings
    result = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    assert not (tmp_path / "s3:").exists()  # a squeezed Path("s3:/…") is never created
    return result.exit_code, result.output


def test_run_on_missing_bucket_is_one_line(tmp_path: Path, s3: str,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    url = "s3://m3gd-no-such-bucket/run"
    assert "no such bucket" in _one_line_error(*_run_on(tmp_path, url), url, "m3gd-secret")


def test_run_on_wrong_endpoint_is_one_line(tmp_path: Path, s3: str,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{free_port()}")
    assert "cannot connect" in _one_line_error(*_run_on(tmp_path, s3), s3, "m3gd-secret")


def test_run_with_refused_credentials_is_one_line(tmp_path: Path, strict_s3: LocalS3,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    for key, value in strict_s3.env.items():
        monkeypatch.setenv(key, value)
    url = "s3://m3gd-test-strict/run"
    text = _one_line_error(*_run_on(tmp_path, url), url, strict_s3.env["AWS_SECRET_ACCESS_KEY"])
    assert "access denied" in text


def test_unreachable_recording_is_one_line(tmp_path: Path, s3: str) -> None:
    url = "s3://m3gd-no-such-bucket/m0"
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {tmp_path / 'out'}\ningest: {{recordings: [{url}]}}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    text = _one_line_error(result.exit_code, result.output, url, "m3gd-secret")
    assert "ingest.recordings" in text and "no such bucket" in text
    assert not (tmp_path / "out" / "manifest.json").exists()


def test_plot_on_s3_uploads_the_statistics_plots(tmp_path: Path, s3: str) -> None:
    import pyarrow.fs as pafs

    from store.object_store import filesystem, parse_url

    _write_shards(tmp_path / "out")
    merge_recording(tmp_path / "out", "rec")
    upload(tmp_path / "out", s3)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {s3}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "plot"])
    assert result.exit_code == 0, result.output
    assert f"{s3}/plots/dtau_hist.png" in result.output.split()
    info = filesystem().get_file_info(parse_url(s3).key("plots/dtau_hist.png"))
    assert info.type == pafs.FileType.File and info.size > 1000  # a whole PNG object
    assert "PCA" in result.output  # says what it did not draw


@pytest.mark.parametrize("args", [["accuracy"], ["align"], ["view"], ["report"],
                                  ["demo"], ["sample"], ["sample", "ck"], ["eval"],
                                  ["bench", "sampler", "--quick"]])
def test_local_only_commands_refuse_s3_in_one_line(tmp_path: Path, args: list[str],
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # a squeezed Path("s3:/…") would be created here
    url = "s3://m3gd-out/run"
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {url}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), *args])
    assert result.exit_code == 2, result.output
    text = result.output.strip()
    assert len(text.splitlines()) == 1 and url in text and "object storage" in text, text
    assert not (tmp_path / "s3:").exists()


def test_unlock_removes_a_lock_object_of_another_host(tmp_path: Path, s3: str) -> None:
    from tests.pipeline.run.test_lock import _plant

    _plant(s3, "elsewhere", 4242)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {s3}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "unlock"])
    assert result.exit_code == 0, result.output
    assert result.output.startswith(f"{s3}: removed the lock of host elsewhere, pid 4242")
    result = CliRunner().invoke(app, ["-c", str(cfg), "unlock", s3])
    assert result.output.strip() == f"{s3}: no lock to remove"
