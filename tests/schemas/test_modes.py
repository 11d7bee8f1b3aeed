"""Packet modes as objects: the paper's five unchanged, the warp modes on top."""

from __future__ import annotations

import pytest

from schemas.channels import n_g
from schemas.config import PacketsConfig
from schemas.errors import DataError
from schemas.modes import MODE_ARRAYS, MODEL_MODES, PACKET_MODES, WARP_MODES, packet_mode


def test_the_paper_modes_are_the_cache_modes_and_unchanged() -> None:
    assert PACKET_MODES == ("full", "geom_only", "zero", "learnable", "no_lidar")
    assert (*PACKET_MODES, "warp", "full_warp") == MODEL_MODES and MODEL_MODES[5:] == WARP_MODES
    assert {m: packet_mode(m).channels(10) for m in PACKET_MODES} == {
        "full": n_g() + 10, "geom_only": n_g(), "zero": n_g() + 10, "learnable": n_g() + 10,
        "no_lidar": 0}
    assert not any(packet_mode(m).warp for m in PACKET_MODES)
    assert all(packet_mode(m).cache_mode == m for m in PACKET_MODES)
    with pytest.raises(ValueError, match="warp"):
        PacketsConfig(mode="warp")  # type: ignore[arg-type]  # a cache holds paper packets


def test_warp_modes_read_the_cache_packets_and_add_c_plus_one_channels() -> None:
    warp, full_warp = packet_mode("warp"), packet_mode("full_warp")
    assert (warp.arrays, warp.cache_mode, warp.reads_h) == (("g",), "geom_only", False)
    assert (full_warp.arrays, full_warp.cache_mode, full_warp.reads_h) == (("g", "h"), "full",
                                                                           True)
    assert MODE_ARRAYS["warp"] == MODE_ARRAYS["geom_only"]
    assert MODE_ARRAYS["full_warp"] == MODE_ARRAYS["full"]
    assert warp.channels(10, 16) == n_g() + 17
    assert full_warp.channels(10, 16) == n_g() + 10 + 17
    assert warp.channels(10, 0) == n_g() + 1  # the validity channel even for C = 0
    with pytest.raises(DataError, match="latent channels"):
        warp.channels(10)


def test_an_unknown_mode_names_every_mode() -> None:
    with pytest.raises(DataError, match="full_warp"):
        packet_mode("wrap")
