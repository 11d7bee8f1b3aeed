"""Utonia adapter: pre/post-processing on real arrays, the missing-package error, and the
adapter's wiring against a stand-in network (Utonia itself cannot be installed here)."""

from __future__ import annotations

import importlib.util
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
from addict import Dict

from model.encoders.utonia import UtoniaEncoder, UtoniaMissing, import_utonia
from model.encoders.utonia_prep import (
    concat_width,
    grid_sample,
    input_dict,
    pooling_chain,
    prepare,
    unpool_concat,
)
from tests.model.encoders.test_fpfh import scene


def test_input_dict_fills_missing_modalities_with_zeros() -> None:
    xyz, _ = scene(300)
    d = input_dict(xyz)
    assert set(d) == {"coord", "color", "normal"}
    assert all(v.shape == (300, 3) and v.dtype == np.float32 for v in d.values())
    assert not d["color"].any() and not d["normal"].any()
    np.testing.assert_array_equal(d["coord"], xyz)


def test_grid_sample_known_answer() -> None:
    coord = np.array([[0.001, 0, 0], [0.019, 0, 0], [0.005, 0.002, 0], [-0.001, 0, 0]])
    keep, inverse, grid = grid_sample(coord, 0.01)
    # voxels: x-cells -1 (point 3), 0 (points 0, 2), 1 (point 1); first point kept
    assert sorted(keep.tolist()) == [0, 1, 3]
    np.testing.assert_array_equal(keep[inverse], [0, 1, 0, 3])
    np.testing.assert_array_equal(grid[inverse][:, 0], [1, 2, 1, 0])
    assert grid.min() == 0


def test_grid_sample_inverse_on_a_real_sweep() -> None:
    xyz, _ = scene(3000)
    coord = xyz * np.float32(0.2)
    keep, inverse, grid = grid_sample(coord, 0.01)
    cells = np.floor(coord.astype(np.float64) / 0.01).astype(np.int64)
    np.testing.assert_array_equal(cells[keep[inverse]], cells)   # same voxel as its keeper
    assert len(np.unique(cells[keep], axis=0)) == len(keep)      # one point per voxel
    assert np.all(keep <= np.arange(len(coord))[keep])
    first = {}
    for i, c in enumerate(map(tuple, cells)):
        first.setdefault(c, i)
    assert sorted(first.values()) == sorted(keep.tolist())      # the first point of each
    np.testing.assert_array_equal(grid, cells[keep] - cells.min(axis=0))
    assert 0 < len(keep) < len(coord)


def test_prepare_scales_samples_and_assembles_features() -> None:
    xyz, _ = scene(2000)
    inp = prepare(xyz, scale=0.2, grid_size=0.01)
    m = len(inp.coord)
    assert inp.feat.shape == (m, 9) and inp.grid_coord.shape == (m, 3)
    assert inp.inverse.shape == (2000,) and inp.inverse.max() == m - 1
    np.testing.assert_allclose(inp.coord[inp.inverse], xyz * 0.2, atol=0.01 * np.sqrt(3))
    np.testing.assert_array_equal(inp.feat[:, :3], inp.coord)
    assert not inp.feat[:, 3:].any()
    d = inp.as_dict()
    assert d["offset"].tolist() == [m] and set(d) == {"coord", "grid_coord", "feat", "offset",
                                                      "inverse"}
    assert len(prepare(np.zeros((0, 3), np.float32)).coord) == 0


def three_stages() -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Real pooling of a sweep: stage k = grid sample of stage k-1 at twice the grid."""
    xyz, _ = scene(1200)
    coord = xyz.astype(np.float64) * 0.2
    feats, inverses, grid = [], [], 0.02
    rng = np.random.default_rng(0)
    for width in (2, 3, 4):
        feats.append(rng.standard_normal((len(coord), width)))
        keep, inverse, _ = grid_sample(coord, grid)
        if width != 4:
            inverses.append(inverse)
            coord, grid = coord[keep], grid * 2
    return feats, inverses


def test_unpool_concat_known_answer() -> None:
    f0, f1, f2 = np.array([[1.0], [2.0], [3.0]]), np.array([[10.0], [20.0]]), np.array([[7.0]])
    inv = [np.array([0, 1, 1]), np.array([0, 0])]
    np.testing.assert_array_equal(unpool_concat([f0, f1, f2], inv, 2),
                                  [[1, 10, 7], [2, 20, 7], [3, 20, 7]])
    np.testing.assert_array_equal(unpool_concat([f0, f1, f2], inv, 1),
                                  [[10, 7], [20, 7], [20, 7]])


def test_unpool_concat_on_real_pooling_numpy_and_torch() -> None:
    feats, inverses = three_stages()
    out = unpool_concat(feats, inverses, 2)
    i = np.arange(len(feats[0]))
    expect = np.concatenate([feats[0], feats[1][inverses[0]],
                             feats[2][inverses[1][inverses[0]]]], axis=1)
    np.testing.assert_array_equal(out, expect)
    tout = unpool_concat([torch.from_numpy(f) for f in feats],
                         [torch.from_numpy(v) for v in inverses], 2)
    np.testing.assert_array_equal(tout.numpy(), out)
    assert out.shape == (len(i), 2 + 3 + 4)
    with pytest.raises(ValueError, match="n_concat=3"):
        unpool_concat(feats, inverses, 3)


def test_pooling_chain_walks_utonia_point_structure() -> None:
    feats, inverses = three_stages()
    p0 = Dict(feat=feats[0])
    p1 = Dict(feat=feats[1], pooling_parent=p0, pooling_inverse=inverses[0])
    p2 = Dict(feat=feats[2], pooling_parent=p1, pooling_inverse=inverses[1])
    got_f, got_i = pooling_chain(p2)
    assert [f is g for f, g in zip(got_f, feats, strict=True)] == [True] * 3
    assert [a is b for a, b in zip(got_i, inverses, strict=True)] == [True] * 2
    assert "pooling_parent" in p2  # not consumed


def test_paper_width() -> None:
    assert concat_width((48, 96, 216, 432, 576), 2) == 1224
    assert concat_width((48, 96, 216, 432, 576), 0) == 576


@pytest.mark.skipif(importlib.util.find_spec("utonia") is not None, reason="utonia installed")
def test_missing_package_says_how_to_install(tmp_path: Path) -> None:
    with pytest.raises(UtoniaMissing) as err:
        UtoniaEncoder(tmp_path / "utonia.pth")
    msg = str(err.value)
    for needle in ("git clone https://github.com/Pointcept/Utonia", "spconv", "torch-scatter",
                   "utonia.pth", "enable_flash=False"):
        assert needle in msg
    assert isinstance(err.value, ImportError)


def write_package(root: Path, model_src: str) -> Path:
    pkg = root / "utonia"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "model.py").write_text(textwrap.dedent(model_src))
    return root


@pytest.fixture
def clean_imports(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setattr(sys, "path", list(sys.path))
    for name in ("utonia", "utonia.model"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    yield
    for name in ("utonia", "utonia.model"):
        sys.modules.pop(name, None)


def test_clone_without_compiled_deps_names_the_missing_module(tmp_path: Path,
                                                              clean_imports: None) -> None:
    root = write_package(tmp_path, "import spconv_not_here.pytorch\n")
    with pytest.raises(UtoniaMissing, match="spconv_not_here"):
        import_utonia(root)


STAND_IN = """
    # Test stand-in for utonia.model: real grid pooling, linear stages; NOT Utonia.
    import numpy as np
    import torch
    from addict import Dict

    from model.encoders.utonia_prep import grid_sample

    class PointTransformerV3(torch.nn.Module):
        def __init__(self, enc_channels, enable_flash=True):
            super().__init__()
            assert enable_flash is False, "adapter must disable flash on CPU"
            widths = [9, *enc_channels]
            self.stages = torch.nn.ModuleList(
                torch.nn.Linear(a, b) for a, b in zip(widths[:-1], widths[1:]))

        def forward(self, d):
            point = Dict(feat=self.stages[0](d["feat"]), coord=d["coord"])
            grid = 0.02
            for stage in self.stages[1:]:
                keep, inv, _ = grid_sample(point.coord.numpy(), grid)
                child = Dict(coord=point.coord[keep], pooling_parent=point,
                             pooling_inverse=torch.from_numpy(inv))
                child.feat = stage(point.feat[keep])
                point, grid = child, grid * 2
            return point
"""


def test_adapter_wiring_with_a_stand_in_network(tmp_path: Path, clean_imports: None) -> None:
    root = write_package(tmp_path / "clone", STAND_IN)
    mod = import_utonia(root)
    torch.manual_seed(0)
    net = mod.PointTransformerV3(enc_channels=[4, 5, 6, 7], enable_flash=False)
    ckpt = {"config": {"enc_channels": [4, 5, 6, 7], "enable_flash": True},
            "state_dict": net.state_dict()}
    torch.save(ckpt, tmp_path / "utonia.pth")
    enc = UtoniaEncoder(tmp_path / "utonia.pth", repo_root=root)
    assert enc.out_channels == 5 + 6 + 7 and enc.pretrained
    xyz, inten = scene(900)
    out = enc.encode(xyz, inten)
    assert out.shape == (900, 18) and out.dtype == np.float32 and enc.n_encoded == 1
    inp = prepare(xyz)                       # independent path to the stage features
    coord, grid, feat = inp.coord, 0.02, torch.from_numpy(inp.feat)
    index = inp.inverse                      # raw point -> its point at the current stage
    cols = []
    with torch.no_grad():
        feat = net.stages[0](feat)
        for stage in net.stages[1:]:         # stages 1-3: pool at 0.02, 0.04, 0.08
            keep, inv, _ = grid_sample(coord, grid)
            feat = stage(feat[torch.from_numpy(keep)])
            coord, grid, index = coord[keep], grid * 2, inv[index]
            cols.append(feat.numpy()[index])  # broadcast back to every raw point
    expect = np.concatenate(cols, axis=1)    # n_concat = 2: last 3 stages, widths 5 + 6 + 7
    assert expect.shape == (900, 18)
    assert all(len(np.unique(c, axis=0)) > 1 for c in cols)  # not constant columns
    np.testing.assert_allclose(out, expect, atol=1e-6)
    assert enc.encode(xyz[:0]).shape == (0, 18)


def test_checkpoint_must_hold_config_and_state_dict(tmp_path: Path,
                                                    clean_imports: None) -> None:
    root = write_package(tmp_path / "clone", STAND_IN)
    torch.save({"state_dict": {}}, tmp_path / "bad.pth")
    with pytest.raises(ValueError, match="'config' and 'state_dict'"):
        UtoniaEncoder(tmp_path / "bad.pth", repo_root=root)
    with pytest.raises(FileNotFoundError, match=r"none\.pth"):
        UtoniaEncoder(tmp_path / "none.pth", repo_root=root)
