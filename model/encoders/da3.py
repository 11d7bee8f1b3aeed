"""Depth Anything 3 image encoder (SPEC §7), from the `depth-anything-3` package.

The network is built from the package's own config, `create_object(load_config(
MODEL_REGISTRY["da3-base"]))`, and weights come from a local `model.safetensors`, matched
key by key (no download is attempted). A randomly initialized network is only built with an
explicit `allow_random_init=True`; it then reports `pretrained=False` and a weights hash
'random-init-seed<N>' so the cache metadata cannot pass it off as the real encoder.

Forward: ImageNet normalization, x (B, S=1, 3, H, W) on `device` (a batch of single views:
no image attends to another), `net.backbone(x, cam_token=None,
export_feat_layers=[])` -> (levels, aux); levels[i] = (tokens (B, 1, h*w, 2*768), camera
token (B, 1, 1536)) for blocks 5, 7, 9, 11 (Base); tokens are the concatenation of the local
features and the normalized global features. The patch tokens come out of a strided conv
flattened row-major (`flatten(2)`), so token r*w + c is cell (r, c) and the level reshapes to
(1536, h, w) by a transpose and reshape, as the package's DPT head does.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from model.device import resolve_device
from model.encoders.base import ImageEncoder, file_sha256
from schemas.errors import DataError, MissingInputError

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def build_da3_net(preset: str = "da3-base", seed: int = 0) -> Any:
    """The DA3 network of `preset` (random init from torch RNG seeded `seed`), eval mode."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # omegaconf / torch.jit deprecations at import
        from depth_anything_3.cfg import create_object, load_config
        from depth_anything_3.registry import MODEL_REGISTRY
    if preset not in MODEL_REGISTRY:
        raise DataError(f"DA3 preset {preset!r} unknown; known: {sorted(MODEL_REGISTRY)}")
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        net = create_object(load_config(MODEL_REGISTRY[preset]))
    return net.eval()


def alias_groups(module: torch.nn.Module) -> list[list[str]]:
    """State-dict keys grouped by the tensor they share (tied weights), in key order."""
    groups: dict[tuple[int, int, tuple[int, ...], tuple[int, ...]], list[str]] = {}
    for k, v in module.state_dict().items():
        ident = (v.untyped_storage().data_ptr(), v.storage_offset(), tuple(v.shape),
                 tuple(v.stride()))
        groups.setdefault(ident, []).append(k)
    return list(groups.values())


def load_state_strict(module: torch.nn.Module, path: Path, strip_prefix: str = "model.") -> str:
    """Load a local safetensors file into `module`, every key matched; return its SHA-256.

    Keys that all start with `strip_prefix` (the Hugging Face DA3 wrapper stores the network
    as `.model`) are stripped first. Tied tensors may be stored under one of their names
    only (as `safetensors.torch.save_model` writes them). Raises FileNotFoundError for a
    missing file, KeyError naming missing / unexpected keys, ValueError for a bad shape.
    """
    from safetensors.torch import load_file

    path = Path(path)
    if not path.is_file():
        raise MissingInputError(f"DA3 weights file not found: {path} (expected a local "
                                "model.safetensors; nothing is downloaded)")
    state = load_file(str(path))
    if strip_prefix and state and all(k.startswith(strip_prefix) for k in state):
        state = {k[len(strip_prefix):]: v for k, v in state.items()}
    expected = module.state_dict()
    missing = []
    for group in alias_groups(module):
        present = [k for k in group if k in state]
        missing += [] if present else group
        state.update({k: state[present[0]] for k in group if present and k not in state})
    unexpected = sorted(set(state) - set(expected))
    if missing or unexpected:
        raise KeyError(f"{path}: {len(missing)} missing keys {sorted(missing)[:5]}, "
                       f"{len(unexpected)} unexpected keys {unexpected[:5]}")
    for k, v in expected.items():
        if tuple(state[k].shape) != tuple(v.shape):
            raise DataError(f"{path}: key {k} has shape {tuple(state[k].shape)}, "
                             f"the network expects {tuple(v.shape)}")
    module.load_state_dict(state, strict=True)
    return file_sha256(path)


def tokens_to_grid(tokens: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """Patch tokens (B, h*w, C), row-major cells -> (B, C, h, w)."""
    b, n, c = tokens.shape
    if n != h * w:
        raise DataError(f"DA3: {n} tokens do not fill a {h}x{w} grid")
    return tokens.transpose(1, 2).reshape(b, c, h, w)


class DA3Encoder(ImageEncoder):
    """DA3 backbone features, levels 0-3 = blocks 5, 7, 9, 11 (Base), each image alone."""

    name = "da3"
    version = "0.1.1"

    def __init__(self, weights: str | Path | None = None, *, preset: str = "da3-base",
                 allow_random_init: bool = False, seed: int = 0,
                 levels: tuple[int, ...] = (0, 1, 2, 3), device: str = "cpu") -> None:
        super().__init__()
        if weights is None and not allow_random_init:
            raise DataError("DA3 encoder: no weights path given; pass the local "
                             "model.safetensors, or allow_random_init=True for a random "
                             "network (then marked pretrained=False)")
        self.net = build_da3_net(preset, seed)
        if weights is not None:
            self.weights_hash = load_state_strict(self.net, Path(weights))
            self.pretrained = True
        else:
            self.weights_hash = f"random-init-seed{seed}"
            self.pretrained = False
        self.preset = preset
        self.version = f"0.1.1-{preset}"
        vit = self.net.backbone.pretrained
        self.out_channels = int(vit.embed_dim) * (2 if vit.cat_token else 1)
        n_out = len(self.net.backbone.out_layers)
        if any(lv not in range(n_out) for lv in levels) or not levels:
            raise DataError(f"DA3 levels {levels} not within 0..{n_out - 1}")
        self.levels = tuple(levels)
        self.device = resolve_device(device)
        self.net.to(self.device)
        self._mean = torch.tensor(IMAGENET_MEAN, device=self.device).view(3, 1, 1)
        self._std = torch.tensor(IMAGENET_STD, device=self.device).view(3, 1, 1)

    def normalize(self, images: np.ndarray) -> torch.Tensor:
        """uint8 (B, H, W, 3) or (H, W, 3) -> ImageNet-normalized float32 (B, 1, 3, H, W) on
        the encoder's device (one view per batch entry: images never attend to each other)."""
        x = torch.from_numpy(np.ascontiguousarray(images)).to(self.device)
        x = (x[None] if x.ndim == 3 else x).permute(0, 3, 1, 2).float() / 255.0
        return ((x - self._mean) / self._std)[:, None]

    def _encode_image(self, image: np.ndarray) -> dict[int, np.ndarray]:
        return {lv: z[0] for lv, z in self._forward(image[None]).items()}

    def _encode_batch(self, images: np.ndarray) -> dict[int, np.ndarray]:
        """{level: (B, C, h, w)}: on an accelerator the batch through the backbone at once; on
        the CPU one image at a time, because CPU GEMM kernels round differently by batch size
        (~3e-6 apart on some CPUs) and a cached latent must not depend on its batch-mates."""
        if self.device.type == "cpu":
            return super()._encode_batch(images)
        return self._forward(images)

    @torch.inference_mode()
    def _forward(self, images: np.ndarray) -> dict[int, np.ndarray]:
        """The batch through the backbone at once on the device: {level: (B, C, h, w)}."""
        h, w = images.shape[1] // self.patch, images.shape[2] // self.patch
        levels, _aux = self._backbone(self.normalize(images))
        out: dict[int, np.ndarray] = {}
        for lv in self.levels:
            tokens = levels[lv][0][:, 0]                     # (B, h*w, C)
            out[lv] = tokens_to_grid(tokens, h, w).float().cpu().numpy()  # (B, C, h, w)
        return out

    def _backbone(self, x: torch.Tensor) -> tuple[Any, Any]:
        """Run the backbone on (B, 1, 3, H, W) (one view each) without camera conditioning."""
        levels, aux = self.net.backbone(x, cam_token=None, export_feat_layers=[])
        return levels, aux
