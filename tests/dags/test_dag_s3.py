"""The whole DAG writing to an output on S3 (a moto server on 127.0.0.1): outputs equal to
the same run on local disk, workers without a shared folder, kill and rerun."""

from __future__ import annotations

from pathlib import Path

import pyarrow.fs as pafs
import pytest

from dags.graph import STAGES
from pipeline.run.executors import LocalExecutor
from pipeline.run.runner import Runner
from schemas.object_store import filesystem, parse_url
from tests.dags.conftest import tiny_config
from tests.dags.outputs import assert_same_outputs

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
