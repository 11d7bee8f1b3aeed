"""The temperature trade: two draws agree exactly at temperature 0 and differ at 1; the
spread's arithmetic; seeds averaged per temperature."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from bench.sampler_temperature import Draws, draw_spread, mean_over_seeds, temperature_rows
from model.dataset import ClipStream
from model.encoders.patch import PatchEncoder
from model.evaluate import TargetResult
from model.net import M3GDNet, NetConfig
from tests.model.cache_fixture import CU, GRID, build_cache
from tests.model.test_compare import C, _fill
from tests.model.test_transformer import _perturb


def _result(view: int, value: int) -> TargetResult:
    return TargetResult(0, view, np.full((2, 2, 3), value, np.uint8), None, 10.0, 0.1)


def test_spread_is_the_rms_difference_over_root_two() -> None:
    a = [_result(1, 10), _result(3, 0)]
    b = [_result(1, 14), _result(3, 0)]
    assert draw_spread(a, b) == pytest.approx((4 / math.sqrt(2) + 0) / 2)
    with pytest.raises(ValueError, match="not the same target"):
        draw_spread(a, [_result(2, 10), _result(3, 0)])
    with pytest.raises(ValueError, match="two draws"):
        draw_spread(a, b[:1])


def test_seeds_average_per_temperature() -> None:
    rows = mean_over_seeds([[{"temperature": 0.0, "psnr": 16.0, "ssim": 0.2, "spread": 0.0}],
                            [{"temperature": 0.0, "psnr": 17.0, "ssim": 0.4, "spread": 0.0}]])
    assert rows[0]["psnr"] == 16.5 and rows[0]["psnr_std"] == pytest.approx(math.sqrt(0.5))
    assert rows[0]["spread"] == 0.0 and rows[0]["ssim"] == pytest.approx(0.3)


def test_temperature_zero_draws_agree_and_one_draws_differ(tmp_path: Path) -> None:
    build_cache(tmp_path, channels=(C, CU), fill=_fill)
    torch.manual_seed(0)
    net = M3GDNet(NetConfig(c=C, c_u=CU, grid_hw=(GRID.grid_h, GRID.grid_w),
                            image_hw=(GRID.image_h, GRID.image_w), mode="full", patch=1,
                            adapter_hidden=16)).eval()
    _perturb(net, 4)  # an untrained x-predictor's zero output would ignore the noise
    stream = ClipStream(tmp_path, "eval", "full", shuffle=False, with_images=True)
    rows = temperature_rows(net, stream, PatchEncoder(C), Draws(steps=2, clips=2, batch_size=2),
                            (0.0, 1.0))
    assert [r["temperature"] for r in rows] == [0.0, 1.0]
    assert rows[0]["spread"] == 0.0 and rows[1]["spread"] > 1.0  # 8-bit levels
    assert all(math.isfinite(r["psnr"]) and -1 <= r["ssim"] <= 1 for r in rows)
