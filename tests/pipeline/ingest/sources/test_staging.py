"""Recordings on S3 (a moto server): staged to scratch per item and removed; a run over them
equals the run over the same local missions, output for output."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.ingest.sources.staging import mission_identity, staged
from store.object_store import StorageError
from tests.s3_fixture import upload


def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


def test_staged_copies_then_removes(s3: str, tmp_path: Path,
                                    monkeypatch: pytest.MonkeyPatch) -> None:
    src = tmp_path / "m7"
    (src / "sub").mkdir(parents=True)
    (src / "a.bag").write_bytes(b"x" * 1000)
    (src / "sub" / "b.jpg").write_bytes(bytes(range(256)))
    upload(src, f"{s3}/m7")
    monkeypatch.setenv("M3GD_SCRATCH", str(tmp_path / "scratch"))
    with staged(Path(f"{s3}/m7")) as local:  # as the config hands it: a squeezed Path
        assert local.name == "m7" and _tree(local) == _tree(src)
    assert not any((tmp_path / "scratch").iterdir())  # removed afterwards
    ident = mission_identity(Path(f"{s3}/m7"))
    assert [(i["path"], i["size"]) for i in ident] == [(f"{s3}/m7/a.bag", 1000)]
    with staged(src) as same:  # local missions are read in place
        assert same == src


def test_staging_refusals_are_one_line(s3: str, tmp_path: Path,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    src = tmp_path / "m8"
    src.mkdir()
    (src / "a.bag").write_bytes(b"x" * 1000)
    upload(src, f"{s3}/m8")
    monkeypatch.setenv("M3GD_SCRATCH", str(tmp_path / "scratch"))
    monkeypatch.setenv("M3GD_SCRATCH_BYTES", "999")
    with (pytest.raises(StorageError, match=r"^s3://m3gd-test-\d+/out/m8: .*exceed the scratch"),
          staged(Path(f"{s3}/m8"))):
        pass
    assert not (tmp_path / "scratch").exists() or not any((tmp_path / "scratch").iterdir())
    with (pytest.raises(StorageError, match="no objects below this prefix"),
          staged(Path(f"{s3}/nothing"))):
        pass


def test_run_over_s3_recordings_equals_local(s3: str, tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    from tests.dags.outputs import assert_same_outputs
    from tests.pipeline.ingest.bagkit import Mission, write_mission
    from tests.pipeline.stages.test_stages import _cfg, _run

    missions = [write_mission(tmp_path / "missions", Mission(seconds=2.0, cameras=("front",)),
                              name=f"m{i}") for i in range(2)]
    for m in missions:
        upload(m, f"{s3}/{m.name}")
    monkeypatch.setenv("M3GD_SCRATCH", str(tmp_path / "scratch"))
    _run(_cfg(tmp_path / "local", missions))
    remote = [Path(f"{s3}/{m.name}") for m in missions]
    out = _run(_cfg(tmp_path / "s3out", remote))
    assert not any(s.failed for s in out.values()), {k: s.failed for k, s in out.items()}
    assert_same_outputs(tmp_path / "local", tmp_path / "s3out")
    assert not any((tmp_path / "scratch").iterdir())  # every staged copy removed
