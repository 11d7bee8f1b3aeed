"""The reader filesystem bench on a tiny cache: every reader returns the same bytes and a
time per clip, the baseline loaded from a git revision."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from bench.cache_data import CacheBenchSpec
from bench.reader_fs_bench import _reader_at, bench_dir


def test_readers_agree_and_are_timed(tmp_path: Path) -> None:
    spec = CacheBenchSpec(views=16, channels=8, point_channels=4, image_h=56, image_w=84,
                          shard_views=4, clips=6, clip_span=8)
    try:
        baseline = _reader_at("HEAD")
    except (subprocess.CalledProcessError, FileNotFoundError):
        pytest.skip("not a git checkout")
    per_clip = bench_dir(tmp_path, spec, baseline, repeats=1)
    assert set(per_clip) == {"probe", "no_nowait", "pread", "baseline"}
    assert all(v > 0 for v in per_clip.values())
