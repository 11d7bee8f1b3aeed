"""The whole DAG writing to an output on S3 (a moto server on 127.0.0.1): outputs equal to
the same run on local disk, workers without a shared folder, kill and rerun."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.fs as pafs
import pytest
from distributed.diagnostics.plugin import WorkerPlugin

from dags.graph import STAGES
from pipeline.run.executors import DaskExecutor, LocalExecutor
from pipeline.run.runner import Runner
from store.object_store import filesystem, parse_url
from tests.dags.conftest import tiny_config, write_config
from tests.dags.outputs import assert_same_outputs
from tests.s3_fixture import upload

pytestmark = pytest.mark.filterwarnings("ignore")


def download(url: str, local: Path) -> Path:
    """Copy every object below `url` into the folder `local` (for comparing outputs)."""
    pafs.copy_files(parse_url(url).key(""), str(local), source_filesystem=filesystem(),
                    destination_filesystem=pafs.LocalFileSystem())
    return local


@pytest.fixture(scope="module")
def local_reference(recordings: list[Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny run on local disk, in-process."""
    out = tmp_path_factory.mktemp("local")
    summaries = Runner(tiny_config(out, recordings), STAGES, progress=False).run(LocalExecutor())
    assert all(not s.failed for s in summaries), [s.failed for s in summaries]
    return out


def test_in_process_run_on_s3_equals_local(local_reference: Path, recordings: list[Path],
                                           s3: str, tmp_path: Path) -> None:
    summaries = Runner(tiny_config(Path(s3), recordings), STAGES, progress=False).run(
        LocalExecutor())
    assert all(not s.failed for s in summaries), [s.failed for s in summaries]
    assert_same_outputs(local_reference, download(s3, tmp_path / "s3"))


class SeparateScratch(WorkerPlugin):  # type: ignore[misc]
    """Dask worker plugin: this worker's temp and scratch folders are its own directory
    (no folder shared with the driver or the other worker)."""

    name = "m3gd-separate-scratch"

    def setup(self, worker: object) -> None:
        import os
        import tempfile

        own = Path(worker.local_directory) / "own-tmp"  # type: ignore[attr-defined]
        own.mkdir(parents=True, exist_ok=True)
        os.environ["M3GD_SCRATCH"] = os.environ["TMPDIR"] = str(own)
        tempfile.tempdir = str(own)


def _scratch_of(executor: DaskExecutor) -> set[str]:
    """Each worker's scratch folder."""
    import os

    return set(executor.client.run(lambda: os.environ["M3GD_SCRATCH"]).values())


def test_cluster_without_shared_folder_equals_local(local_reference: Path,
                                                   recordings: list[Path], s3: str,
                                                   tmp_path: Path) -> None:
    """Recordings and output on the store, two workers with separate scratch folders."""
    missions = [f"{s3}/missions/{r.name}" for r in recordings]
    for r, url in zip(recordings, missions, strict=True):
        upload(r, url)
    out = f"{s3}/run"
    cfg = tiny_config(Path(out), [Path(m) for m in missions])
    executor = DaskExecutor(workers=2)
    try:
        executor.client.register_plugin(SeparateScratch())
        scratch = _scratch_of(executor)
        summaries = Runner(cfg, STAGES, progress=False).run(executor)
    finally:
        executor.close()
    assert len(scratch) == 2 and not any(s.startswith(str(tmp_path)) for s in scratch)
    assert all(not s.failed for s in summaries), [s.failed for s in summaries]
    assert_same_outputs(local_reference, download(out, tmp_path / "s3"))


def _marks(url: str, stage: str) -> int:
    """Done-marks of `stage` on the store below `url`."""
    found = filesystem().get_file_info(pafs.FileSelector(
        parse_url(url).key("cache_done"), recursive=True, allow_not_found=True))
    return sum(f.base_name.startswith(f"{stage}.") for f in found)


def _wait_for_mark(url: str, stage: str, timeout: float = 300.0) -> bool:
    """Wait until some shard of `stage` is marked done on the store."""
    end = time.time() + timeout
    while time.time() < end:
        if _marks(url, stage):
            return True
        time.sleep(0.2)
    return False


def _secrets() -> list[bytes]:
    """The client's credentials, which no output or log may contain."""
    return [os.environ[k].encode() for k in ("AWS_SECRET_ACCESS_KEY", "AWS_ACCESS_KEY_ID")]


def test_killed_run_on_s3_resumes_to_same_outputs(local_reference: Path, recordings: list[Path],
                                                  s3: str, tmp_path: Path) -> None:
    cfg = write_config(tmp_path / "cfg.yaml", Path(s3), recordings)
    cmd = [sys.executable, "-m", "cli", "-c", str(cfg), "run", "--workers", "2"]
    log = tmp_path / "first.log"
    with log.open("wb") as sink:
        proc = subprocess.Popen(cmd, start_new_session=True, stdout=sink, stderr=sink)
        try:
            assert _wait_for_mark(s3, "packets"), "the run never reached the packets stage"
        finally:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    lock = filesystem().get_file_info(parse_url(s3).key(".m3gd.lock"))
    assert lock.type == pafs.FileType.File  # the dead run's lock object is left behind
    done = subprocess.run(cmd, capture_output=True, timeout=600)
    assert done.returncode == 0, (done.stdout + done.stderr).decode()
    assert b"took over the stale lock" in done.stdout
    out = download(s3, tmp_path / "s3")
    assert not (out / ".m3gd.lock").exists()  # released at the end
    assert_same_outputs(local_reference, out)
    texts = [log.read_bytes(), done.stdout, done.stderr,
             *(p.read_bytes() for p in out.rglob("*") if p.is_file())]
    for secret in _secrets():
        assert not any(secret in t for t in texts), secret


@pytest.mark.slow
def test_demo_sized_cluster_run_on_s3_equals_local(s3: str, tmp_path: Path) -> None:
    """The demo's configuration (two 6 s recordings, three cameras, default sizes) on a
    LocalCluster of 2: on local disk, and on S3 with workers on separate scratch folders."""
    from schemas.config import M3GDConfig

    def run(out: Path, separate: bool) -> None:
        executor = DaskExecutor(workers=2)
        try:
            if separate:
                executor.client.register_plugin(SeparateScratch())
            summaries = Runner(M3GDConfig(output_dir=out), STAGES, progress=False).run(executor)
        finally:
            executor.close()
        assert all(not s.failed for s in summaries), [s.failed for s in summaries]

    run(tmp_path / "local", separate=False)
    run(Path(s3), separate=True)
    assert_same_outputs(tmp_path / "local", download(s3, tmp_path / "s3"))



def _files(folder: Path, *under: str) -> list[str]:
    """Relative paths of the files below the `under` folders of `folder` (sorted)."""
    return sorted(p.relative_to(folder).as_posix() for u in under
                  for p in (folder / u).rglob("*") if p.is_file())


def test_stats_on_s3_removes_parts_and_marks_past_the_last_shard(
        local_reference: Path, recordings: list[Path], s3: str, tmp_path: Path) -> None:
    """What an earlier layout with more shards leaves on the store (a latent statistics part,
    a statistics part, encode and packets done-marks past the last shard) is deleted from the
    store by the stats stage: the output then equals a fresh run, object for object."""
    cfg = tiny_config(Path(s3), recordings)
    assert not any(s.failed for s in Runner(cfg, STAGES, progress=False).run(LocalExecutor()))
    first = download(s3, tmp_path / "first")
    plant = tmp_path / "plant"
    old = {"stats/latent_parts/t_corridor/front-000009.json":
           "stats/latent_parts/t_corridor/front-000000.json",
           "stats/parts/t_corridor/view_stats-front-000009.parquet":
           "stats/parts/t_corridor/view_stats-front-000000.parquet",
           "cache_done/t_corridor/front/encode.000009.json":
           "cache_done/t_corridor/front/encode.000000.json",
           "cache_done/t_warehouse/front/packets.000009.json":
           "cache_done/t_warehouse/front/packets.000000.json"}
    for rel, source in old.items():
        (plant / rel).parent.mkdir(parents=True, exist_ok=True)
        (plant / rel).write_bytes((first / source).read_bytes())
    upload(plant, s3)
    derived = ("cache_done", "stats/latent_parts", "stats/parts")
    assert set(old) <= set(_files(download(s3, tmp_path / "planted"), *derived))
    summaries = Runner(cfg, STAGES, progress=False).run(LocalExecutor(), force=["stats"])
    assert not any(s.failed for s in summaries), [s.failed for s in summaries]
    out = download(s3, tmp_path / "s3")
    assert _files(out, *derived) == _files(local_reference, *derived)
    assert_same_outputs(local_reference, out)


def test_rerun_on_s3_after_shard_views_change_equals_fresh_local_run(
        local_reference: Path, recordings: list[Path], s3: str, tmp_path: Path) -> None:
    """Arrays recreated with another chunk layout (`cache.shard_views` changed between runs)
    leave no object of the old layout on the store: the rerun succeeds and the output equals
    a fresh local run with the new config, object for object."""
    changed_cfg = tiny_config(Path(s3), recordings)
    cfg = changed_cfg.model_copy(update={"cache": changed_cfg.cache.model_copy(
        update={"shard_views": 3})})  # more, smaller shards first
    assert not any(s.failed for s in Runner(cfg, STAGES, progress=False).run(LocalExecutor()))
    summaries = Runner(changed_cfg, STAGES, progress=False).run(LocalExecutor())
    assert not any(s.failed for s in summaries), [s.failed for s in summaries]
    local = local_reference  # a fresh local run of the tiny config, shard_views as changed_cfg
    out = download(s3, tmp_path / "s3")
    layout = ("cache.zarr", "cache_done")
    assert _files(out, *layout) == _files(local, *layout)
    assert_same_outputs(local, out)
