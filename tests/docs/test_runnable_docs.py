"""The guides' runnable shell blocks, executed in order on tiny synthetic data.

The data engineers' guide makes the output (`tiny.yaml`, `out/`) that the analysts' and
trainers' guides use, as their text says; each guide's blocks run in one bash with `-e`, so the
first failing command fails the test with its output.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.docs.runnable import DOCS, guide, runnable_blocks

REPO = DOCS.parent
GUIDES = ("data_engineers", "trainers", "analysts")


def run_blocks(blocks: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """Run `blocks` as one bash script (-e, pipefail) in `cwd` with this checkout's m3gd."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "MPLBACKEND": "Agg",
           "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    script = "set -euo pipefail\n" + "\n".join(blocks)
    return subprocess.run(["bash", "-c", script], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=900)


def check(result: subprocess.CompletedProcess[str]) -> str:
    """stdout of a successful run; a failure shows both streams."""
    assert result.returncode == 0, f"stdout:\n{result.stdout}\nstderr:\n{result.stderr}"
    return result.stdout


@pytest.fixture(scope="module")
def tiny_output(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A folder where the data engineers' guide ran: (folder, its stdout)."""
    where = tmp_path_factory.mktemp("guide")
    return where, check(run_blocks(runnable_blocks(guide("data_engineers")), where))


@pytest.mark.parametrize("name", GUIDES)
def test_every_guide_has_runnable_blocks(name: str) -> None:
    assert len(runnable_blocks(guide(name))) >= 2


def test_marker_without_a_shell_block_is_refused(tmp_path: Path) -> None:
    page = tmp_path / "p.md"
    page.write_text("<!-- runnable -->\n```text\nprint(1)\n```\n")
    with pytest.raises(ValueError, match="1 runnable markers but 0 shell blocks"):
        runnable_blocks(page)


def test_data_engineers_guide_runs(tiny_output: tuple[Path, str]) -> None:
    where, out = tiny_output
    assert "m3gd run summary" in out
    for name in ("cache.zarr", "index", "stats", "clips.parquet", "manifest.json"):
        assert (where / "out" / name).exists(), name


def test_analysts_guide_runs(tiny_output: tuple[Path, str]) -> None:
    where, _ = tiny_output
    result = run_blocks(runnable_blocks(guide("analysts")), where)
    out = check(result)
    for line in ("align views: ", "accuracy views: ", "view views: 10/10 (100 %)"):
        assert line in result.stderr  # progress lines, stderr being a pipe
    assert (where / "out" / "report.html").exists()
    assert (where / "out" / "stats" / "alignment.parquet").exists()
    assert list((where / "out" / "view").glob("*.rrd"))
    assert "dtau_exceeded" in out or "(no rows)" in out  # the rejects summary printed


@pytest.mark.slow
def test_trainers_guide_runs(tiny_output: tuple[Path, str]) -> None:
    where, _ = tiny_output
    result = run_blocks(runnable_blocks(guide("trainers")), where)
    out = check(result)
    assert "valid views; view" in out  # the zarr-python reader printed
    assert "score clips: 2/2 (100 %)" in result.stderr  # eval's progress, redirected
    from model.checkpoint import has_checkpoint

    assert has_checkpoint(where / "out" / "train" / "full")
    assert "copy-nearest-source" in out
    assert "the recipe measured to beat both baselines" in " ".join(out.split())


def test_a_python_block_runs_as_python_and_is_highlighted_as_python(tmp_path: Path) -> None:
    page = tmp_path / "p.md"
    page.write_text("<!-- runnable -->\n```python\nimport sys\nprint(sys.version_info[0])\n```\n")
    (script,) = runnable_blocks(page)
    assert check(run_blocks([script], tmp_path)) == "3\n"


def test_python_api_training_loop_runs(tiny_output: tuple[Path, str]) -> None:
    """The custom training loop of the Python API page, saved as a script and run as a user
    runs it (`python train_loop.py`, two spawned loader workers importing it), on the
    guide's tiny output."""
    where, _ = tiny_output
    text = guide("reference/python_api").read_text()
    code = text.split("<!-- runnable -->\n```python\n", 1)[1].split("\n```", 1)[0]
    assert "num_workers=2" in code and 'if __name__ == "__main__":' in code
    (where / "train_loop.py").write_text(code + "\n")
    out = check(run_blocks(["python train_loop.py"], where))
    steps = [line for line in out.splitlines() if line.startswith("step ")]
    assert [s.split(":")[0] for s in steps] == ["step 0", "step 1", "step 2"], out
    losses = [float(s.split("loss ")[1].split(",")[0]) for s in steps]
    assert all(math.isfinite(v) and v > 0 for v in losses), losses
    assert all("h torch.float16 (" in s for s in steps), steps  # packed rows, as stored
    # the workers take turns: batches 0 and 2 from worker 0 (2 clips each), batch 1 from
    # worker 1 (its share of the tiny output's train clips is one clip)
    assert "resume state: {'epoch': 0, 'consumed': {'0': 4, '1': 1}}" in out, out
