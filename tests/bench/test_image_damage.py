"""The image-damage probe: its flips stay in the entropy data, its score sees a local blip."""

from __future__ import annotations

import numpy as np
import simplejpeg

from bench.image_damage import flip, mcu_score
from pipeline.ingest.checks.image_checks import Cells


def test_flip_touches_only_the_entropy_data() -> None:
    img = (np.arange(64 * 64 * 3) % 251).astype(np.uint8).reshape(64, 64, 3)
    raw = simplejpeg.encode_jpeg(img, quality=90)
    start = raw.find(b"\xff\xda") + 20
    for seed in range(20):
        bad = flip(raw, np.random.default_rng(seed))
        assert bad[:start] == raw[:start] and bad != raw and len(bad) == len(raw)


def test_mcu_score_of_a_local_blip_against_agreeing_neighbours() -> None:
    base = np.zeros((3, 4, 4), np.float32)
    a, b = Cells(0, base), Cells(2, base)
    blip = base.copy()
    blip[0, 1, 2] = 40.0
    assert mcu_score(Cells(1, blip), a, b, k=1.0) == 40.0
    moving = base.copy()
    moving[0, 1, 2] = 40.0  # the neighbours disagree there as much: motion, not damage
    assert mcu_score(Cells(1, blip), a, Cells(2, moving), k=1.0) == 0.0
