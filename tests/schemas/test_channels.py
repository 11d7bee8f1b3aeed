"""The channel and mode tables drive everything downstream: a dummy channel added to a
temporary copy of schemas.channels.PACKET_CHANNELS (and its formula) changes the cache
shape, the packet statistics, the model's channel counts, the viewer and the docs reference;
a dummy stage added to a copy of the stage list is ordered, planned and run by the service."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from schemas import channels
from schemas.modes import MODE_SPECS, MODEL_MODES, PACKET_MODES, packet_mode

DUMMY = channels.PacketChannel("dummy_count", "–", "n_q again (a test channel)")


@pytest.fixture
def dummy_channel(monkeypatch: pytest.MonkeyPatch) -> int:
    """The table with one more channel, inserted before delta tau; returns the new n_g."""
    from packets import statistics

    table = list(channels.PACKET_CHANNELS)
    table.insert(channels.channel_index(channels.DELTA_TAU), DUMMY)
    monkeypatch.setattr(channels, "PACKET_CHANNELS", tuple(table))
    monkeypatch.setitem(statistics.FORMULAS, DUMMY.name, lambda c: c.n)
    return len(table)


def test_the_table_is_eq_9() -> None:
    assert channels.channel_names() == ("validity", "log1p_mean_depth", "inv_mean_depth",
                                        "log1p_count", "depth_variance", "delta_tau_s")
    assert channels.n_g() == channels.N_G == 6
    assert channels.channel_index(channels.DELTA_TAU) == 5
    with pytest.raises(KeyError, match="no packet channel 'nope'"):
        channels.channel_index("nope")


def test_a_dummy_channel_reaches_statistics_and_the_cache_shape(dummy_channel: int) -> None:
    from packets.statistics import CellStats, explicit_channels
    from schemas.cache_layout import GridSpec, packet_arrays
    from schemas.packed_cells import occupied_cells

    stats = CellStats(n=np.array([0, 3]), mean=np.array([0.0, 2.0]), var=np.array([0.0, 0.5]))
    g = explicit_channels(stats, 0.25, (1, 2))
    assert g.shape == (dummy_channel, 1, 2)
    k = channels.channel_index(DUMMY.name)
    assert g[k, 0, 1] == 3.0 and g[k + 1, 0, 1] == 0.25  # delta tau moved one down
    assert not g[:, 0, 0].any()  # empty cells zero in every channel
    (spec,) = packet_arrays(GridSpec(28, 42), 8, with_h=False)
    assert spec.view_shape == (dummy_channel, 2, 3)
    assert occupied_cells(g[None]).tolist() == [[[False, True]]]


def test_a_dummy_channel_reaches_the_model_and_the_viewer(dummy_channel: int) -> None:
    from model.adapter import ResidualAdapter, build_packet, packet_channels, without_dtau
    from pipeline.analysis.view.scene import packet_channels as view_channels

    c_u = 4
    assert packet_channels("full", c_u) == dummy_channel + c_u
    assert packet_channels("geom_only", c_u) == dummy_channel
    assert ResidualAdapter(8, c_u, "full").conv_in.in_features == 8 + dummy_channel + c_u + 1
    g = torch.ones(1, 2, dummy_channel, 2, 3)
    h = torch.ones(1, 2, 2, 3, c_u)
    ell = build_packet("full", g, h, c_u, torch.zeros(1, 2, 8, 2, 3))
    assert ell is not None and ell.shape == (1, 2, 2, 3, dummy_channel + c_u)
    dropped = without_dtau(ell)
    k = channels.channel_index(channels.DELTA_TAU)
    assert not dropped[..., k].any() and dropped[..., k - 1].all()
    images = view_channels(np.ones((dummy_channel, 2, 3), np.float32))
    assert images["dtau_s"].shape == (2, 3)


def test_a_dummy_channel_reaches_the_docs_reference(dummy_channel: int) -> None:
    from docs_gen import cache_ref

    page = cache_ref.render()
    assert "## g: the seven explicit packet channels" in page
    assert f"| 5 | `{DUMMY.name}` | {DUMMY.meaning} | – |" in page
    assert "| 6 | `delta_tau_s` |" in page
    assert f"`(N, {dummy_channel}, 16, 24)`" in page


def test_modes_carry_their_behaviour() -> None:
    assert tuple(MODE_SPECS) == MODEL_MODES and MODEL_MODES[:len(PACKET_MODES)] == PACKET_MODES
    widths = {m: packet_mode(m).channels(10) for m in PACKET_MODES}
    assert widths == {"full": 16, "geom_only": 6, "zero": 16, "learnable": 16, "no_lidar": 0}
    assert [m for m in PACKET_MODES if packet_mode(m).reads_h] == ["full"]
    assert [m for m in PACKET_MODES if packet_mode(m).has_tensor] == ["full", "geom_only", "zero"]
    with pytest.raises(ValueError, match="unknown packet mode 'magic'"):
        packet_mode("magic")


def test_a_dummy_stage_is_ordered_planned_and_run_by_the_service(tmp_path: Path) -> None:
    from pipeline.run.service import RunRequest, run_stages
    from pipeline.run.stage import Item, ItemResult, Stage
    from schemas.config import parse_config
    from tests.pipeline.run.toy_stages import STAGES

    def plan(cfg):  # type: ignore[no-untyped-def]
        return [Item("rec_a", "k1")]

    def run(cfg, item):  # type: ignore[no-untyped-def]
        (cfg.output_dir / "dummy.txt").write_text((cfg.output_dir / "rec_a.second").read_text())
        return ItemResult(done=1)

    dummy = Stage("dummy", ("second",), plan, run)
    stages = [dummy, *STAGES]  # listed first: the graph orders it after what it reads
    cfg = parse_config({"output_dir": str(tmp_path)})
    outcome = run_stages(cfg, stages)
    names = [s.name for s in outcome.summaries]
    assert names.index("dummy") > names.index("second")
    assert (tmp_path / "dummy.txt").read_text() == (tmp_path / "rec_a.second").read_text()
    again = run_stages(cfg, stages, RunRequest(force=("dummy",)))
    assert {s.name: s.done for s in again.summaries}["dummy"] == 1
    assert {s.name: s.done for s in again.summaries}["first"] == 0  # upstream kept
