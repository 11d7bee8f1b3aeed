"""Utonia point encoder adapter (SPEC §7): Pointcept's pre-trained PTv3, weights from a path.

Utonia is not on PyPI and needs spconv and torch-scatter; it cannot be installed on these
machines, so the package is imported lazily and a missing package raises `UtoniaMissing`
with the install steps. Pre- and post-processing live in `utonia_prep` (pure, tested).
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from typing import Any

import numpy as np

from model.encoders.base import PointEncoder, file_sha256
from model.encoders.utonia_prep import (
    GRID_SIZE,
    OUTDOOR_SCALE,
    concat_width,
    pooling_chain,
    prepare,
    unpool_concat,
)
from schemas.errors import DataError, M3GDError, MissingInputError

INSTALL_HINT = """\
Utonia is not installed ({err}). It is not on PyPI; install it by hand where it can be:
  git clone https://github.com/Pointcept/Utonia && cd Utonia
  pip install spconv            # CPU build; spconv-cu<CUDA> on a GPU machine
  pip install torch-scatter -f https://data.pyg.org/whl/torch-<TORCH_VERSION>+cpu.html
  pip install huggingface_hub timm addict
  python setup.py install       # or pass repo_root=<the clone> to the adapter
Weights: fetch utonia.pth (a dict with 'config' and 'state_dict') from
https://huggingface.co/Pointcept/Utonia on a machine with network access and pass its local
path. On CPU the adapter sets enable_flash=False (flash-attn needs CUDA)."""


class UtoniaMissing(M3GDError, ImportError):
    """The Utonia package (or one of its compiled dependencies) cannot be imported."""


def import_utonia(repo_root: str | Path | None = None) -> Any:
    """Import `utonia.model` (from `repo_root` if given); UtoniaMissing with install steps."""
    if repo_root is not None and str(repo_root) not in sys.path:
        sys.path.insert(0, str(repo_root))
    try:
        return importlib.import_module("utonia.model")
    except ImportError as err:
        raise UtoniaMissing(INSTALL_HINT.format(err=err)) from err


def read_checkpoint(path: Path) -> dict[str, Any]:
    """torch.load a Utonia checkpoint; it must hold 'config' and 'state_dict'."""
    import torch

    if not path.is_file():
        raise MissingInputError(f"Utonia weights not found: {path} (a local utonia.pth)")
    ckpt = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(ckpt, dict) or not {"config", "state_dict"} <= set(ckpt):
        keys = sorted(ckpt) if isinstance(ckpt, dict) else type(ckpt).__name__
        raise DataError(f"{path}: a Utonia checkpoint needs 'config' and 'state_dict', "
                         f"found {keys}")
    return ckpt


class UtoniaEncoder(PointEncoder):
    """Utonia features per point: the last `n_concat` + 1 stages concatenated (1224 ch)."""

    name = "utonia"
    version = "1"
    pretrained = True

    def __init__(self, weights: str | Path, *, repo_root: str | Path | None = None,
                 scale: float = OUTDOOR_SCALE, grid_size: float = GRID_SIZE,
                 n_concat: int = 2, device: str = "cpu") -> None:
        super().__init__()
        utonia_model = import_utonia(repo_root)
        path = Path(weights)
        ckpt = read_checkpoint(path)
        config = dict(ckpt["config"])
        if device == "cpu":
            config["enable_flash"] = False
        self.net = utonia_model.PointTransformerV3(**config)
        self.net.load_state_dict(ckpt["state_dict"], strict=True)
        self.net = self.net.to(device).eval()
        self.device = device
        self.scale, self.grid_size, self.n_concat = scale, grid_size, n_concat
        self.out_channels = concat_width(config["enc_channels"], n_concat)
        self.weights_hash = file_sha256(path)

    def _encode_sweep(self, xyz: np.ndarray, intensity: np.ndarray | None) -> np.ndarray:
        """Intensity is not a Utonia modality and is ignored (color and normal are zeros)."""
        import torch

        if xyz.shape[0] == 0:
            return np.zeros((0, self.out_channels), np.float32)
        inp = prepare(xyz, scale=self.scale, grid_size=self.grid_size)
        batch = {k: torch.from_numpy(v).to(self.device) for k, v in inp.as_dict().items()}
        with torch.inference_mode():
            point = self.net(batch)
            feats, inverses = pooling_chain(point)
            feat = unpool_concat(feats, inverses, self.n_concat)     # (M, C_u)
        out: np.ndarray = feat.float().cpu().numpy()[inp.inverse]  # (N, C_u)
        return out
