"""The Depth Anything 3 encoder: contract suite (random init, 224x336) and weight loading."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import save_file, save_model

from model.encoders.base import file_sha256
from model.encoders.da3 import DA3Encoder, build_da3_net, load_state_strict, tokens_to_grid
from tests.model.encoders.contract import ImageEncoderContract, smooth_images


class TestDA3Encoder(ImageEncoderContract):
    image_hw = (224, 336)
    batch = 2

    def make(self, seed: int) -> DA3Encoder:
        return DA3Encoder(allow_random_init=True, seed=seed)

    def test_paper_shapes_and_random_init_identity(self, encoder: DA3Encoder,
                                                   encoded: dict) -> None:
        assert encoder.levels == (0, 1, 2, 3)
        assert all(z.shape == (2, 1536, 16, 24) for z in encoded.values())
        ident = encoder.identity()
        assert ident.pretrained is False and ident.weights_hash == "random-init-seed0"
        assert not np.array_equal(encoded[0], encoded[3])


def test_weights_or_explicit_flag_required() -> None:
    with pytest.raises(ValueError, match="allow_random_init"):
        DA3Encoder()


def test_tokens_are_row_major_cells() -> None:
    """Patch tokens reshaped by tokens_to_grid equal the patch-embedding conv output map."""
    net = build_da3_net("da3-base", seed=0)
    embed = net.backbone.pretrained.patch_embed
    assert isinstance(embed.norm, torch.nn.Identity)
    x = torch.randn(1, 3, 28, 42)
    with torch.no_grad():
        conv = embed.proj(x)                                          # (1, C, 2, 3)
        tokens = embed(x)                                             # (1, 6, C)
    np.testing.assert_array_equal(tokens_to_grid(tokens, 2, 3).numpy(), conv.numpy())
    column_major = tokens_to_grid(tokens, 3, 2).transpose(2, 3)      # the other reading
    assert not torch.equal(column_major, conv)


class Tiny(torch.nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.a = torch.nn.Linear(3, 2)
        self.b = torch.nn.Linear(2, 1)


class Tied(Tiny):
    def __init__(self) -> None:
        super().__init__()
        self.c = torch.nn.Linear(2, 1)
        self.c.weight = self.b.weight  # tied, like DA3's auxiliary head convs


class Wrapper(torch.nn.Module):
    """The Hugging Face DA3 layout: the network stored as `.model`."""

    def __init__(self, net: torch.nn.Module) -> None:
        super().__init__()
        self.model = net


def save(path: Path, state: dict[str, torch.Tensor]) -> Path:
    save_file({k: v.contiguous() for k, v in state.items()}, str(path))
    return path


def test_strict_load_roundtrip_and_prefix(tmp_path: Path) -> None:
    src, dst = Tiny(), Tiny()
    path = save(tmp_path / "model.safetensors",
                {f"model.{k}": v for k, v in src.state_dict().items()})
    assert load_state_strict(dst, path) == file_sha256(path)
    for k, v in src.state_dict().items():
        assert torch.equal(dst.state_dict()[k], v)


def test_strict_load_names_missing_and_unexpected_keys(tmp_path: Path) -> None:
    state = Tiny().state_dict()
    missing = save(tmp_path / "m.safetensors", {k: v for k, v in state.items() if k != "b.bias"})
    with pytest.raises(KeyError, match=r"1 missing keys \['b.bias'\]"):
        load_state_strict(Tiny(), missing)
    extra = save(tmp_path / "u.safetensors", {**state, "c.weight": torch.zeros(1)})
    with pytest.raises(KeyError, match=r"1 unexpected keys \['c.weight'\]"):
        load_state_strict(Tiny(), extra)
    bad = save(tmp_path / "s.safetensors", {**state, "b.bias": torch.zeros(2)})
    with pytest.raises(ValueError, match=r"b\.bias"):
        load_state_strict(Tiny(), bad)


def test_strict_load_accepts_tied_weights_stored_once(tmp_path: Path) -> None:
    src, dst = Tied(), Tied()
    save_model(Wrapper(src), str(tmp_path / "model.safetensors"))  # drops one tied name
    load_state_strict(dst, tmp_path / "model.safetensors")
    assert torch.equal(dst.c.weight, src.b.weight) and dst.c.weight is dst.b.weight
    state = {k: v for k, v in src.state_dict().items() if k not in ("b.weight", "c.weight")}
    with pytest.raises(KeyError, match=r"2 missing keys \['b.weight', 'c.weight'\]"):
        load_state_strict(Tied(), save(tmp_path / "x.safetensors", state))


def test_missing_weights_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"nope\.safetensors"):
        DA3Encoder(tmp_path / "nope.safetensors")


def test_full_checkpoint_loads_and_reproduces(tmp_path: Path) -> None:
    """A full DA3 checkpoint in the Hugging Face layout ('model.' keys) loads strictly."""
    ref = DA3Encoder(allow_random_init=True, seed=5, levels=(0,))
    path = tmp_path / "model.safetensors"
    save_model(Wrapper(ref.net), str(path))  # as PyTorchModelHubMixin writes it
    enc = DA3Encoder(path, levels=(0,))
    assert enc.pretrained is True and enc.weights_hash == file_sha256(path)
    img = smooth_images(1, (28, 42), seed=0)
    np.testing.assert_array_equal(enc.encode(img)[0], ref.encode(img)[0])
