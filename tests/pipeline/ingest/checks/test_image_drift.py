"""The image_drift hold shared by the bag stream and the gated pass: each image judged once its
camera's next image is known, against that one and the last accepted one; never against an
unjudged image alone; a refused image never becomes a neighbour."""

from __future__ import annotations

import numpy as np

from pipeline.ingest.checks.image_drift import DriftHold, drift_on
from schemas.config import ChecksConfig
from tests.pipeline.ingest.checks.test_image_checks import drifted, frame, jpeg_cells

DELTA = np.array([40, -40, 0])


def _stream(bad: set[int], n: int = 10, active: bool = True) -> list[tuple[int, str | None]]:
    """(frame, problem) of frames 0..n-1 of one camera through a hold; `bad` frames drifted."""
    hold = DriftHold(ChecksConfig(), lambda _: active)
    out = []
    for i in range(n):
        rgb = drifted(frame(i), 3 * 15, DELTA) if i in bad else frame(i)
        out += hold.push("front", i, jpeg_cells(rgb, i))
    return out + hold.flush()


def test_a_drifted_frame_is_refused_and_its_neighbours_kept() -> None:
    got = _stream({4})
    assert [i for i, _ in got] == list(range(10))  # every frame judged once, in order
    refused = [i for i, p in got if p is not None]
    assert refused == [4]
    assert "damaged JPEG data decoded without an error" in str(got[4][1])


def test_the_first_frame_is_judged_against_no_unjudged_frame_alone() -> None:
    """Frame 0 has no accepted neighbour: it is not judged against frame 1 alone (a damaged
    frame 1 would cost it), so it is kept; frame 1 is then refused against 0 and 2."""
    got = _stream({1})
    assert got[0] == (0, None) and got[1][1] is not None
    assert all(p is None for i, p in got if i != 1)


def test_an_inactive_check_judges_nothing() -> None:
    assert all(p is None for _, p in _stream({4}, active=False))


def test_flush_and_pop_release_by_camera() -> None:
    hold = DriftHold(ChecksConfig(), lambda _: True)
    for key in ("right", "front"):
        assert hold.push(key, key, jpeg_cells(frame(0), 0)) == []
    assert hold.pop("right") == [("right", None)] and hold.pop("right") == []
    hold.push("left", "left", jpeg_cells(frame(0), 0))
    assert [k for k, _ in hold.flush()] == ["front", "left"]  # by key


def test_drift_on_follows_the_config() -> None:
    assert drift_on(ChecksConfig())
    assert not drift_on(ChecksConfig(enabled=False))
    assert not drift_on(ChecksConfig(image_step_z=0, image_blip_levels=0))
    assert drift_on(ChecksConfig(image_step_z=0))
