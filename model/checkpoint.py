"""Checkpoints without pickle: tensors in one safetensors file, everything else in JSON.

Layout of a checkpoint directory:
  tensors.safetensors  model.<name>, ema.<name>, opt.<param index>.<state key>, rng.generator
  state.json           {"format": FORMAT, "step": int, "net": {...}, "train": {...},
                        "param_groups": [...], "opt_keys": {index: [state keys]}}
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file
from torch import Tensor

from schemas.errors import DataError

FORMAT = "m3gd-checkpoint/1"
TENSORS = "tensors.safetensors"
STATE = "state.json"


def flatten_optimizer(opt: torch.optim.Optimizer) -> tuple[dict[str, Tensor], dict[str, Any]]:
    """Optimizer state as tensors {opt.<i>.<key>} plus JSON {param_groups, opt_keys}."""
    sd = opt.state_dict()
    tensors: dict[str, Tensor] = {}
    keys: dict[str, list[str]] = {}
    for idx, st in sd["state"].items():
        keys[str(idx)] = []
        for k, v in st.items():
            if not isinstance(v, Tensor):
                raise TypeError(f"optimizer state {idx}.{k} is not a tensor: {type(v).__name__}")
            tensors[f"opt.{idx}.{k}"] = v.detach().clone().contiguous()
            keys[str(idx)].append(k)
    return tensors, {"param_groups": sd["param_groups"], "opt_keys": keys}


def unflatten_optimizer(tensors: dict[str, Tensor], meta: dict[str, Any]) -> dict[str, Any]:
    """Inverse of `flatten_optimizer`: a dict for `Optimizer.load_state_dict`."""
    state = {int(i): {k: tensors[f"opt.{i}.{k}"] for k in ks} for i, ks in meta["opt_keys"].items()}
    groups = [{**g, "betas": tuple(g["betas"])} if "betas" in g else g
              for g in meta["param_groups"]]
    return {"state": state, "param_groups": groups}


def save_checkpoint(path: Path, tensors: dict[str, Tensor], meta: dict[str, Any]) -> None:
    """Write `tensors` and `meta` (JSON-compatible) into directory `path` (created)."""
    path.mkdir(parents=True, exist_ok=True)
    save_file({k: v.detach().contiguous() for k, v in tensors.items()}, str(path / TENSORS))
    (path / STATE).write_text(json.dumps({"format": FORMAT, **meta}, indent=1))


def load_checkpoint(path: Path) -> tuple[dict[str, Tensor], dict[str, Any]]:
    """Read a checkpoint directory written by `save_checkpoint`."""
    try:
        meta = json.loads((path / STATE).read_text())
        tensors = load_file(str(path / TENSORS))
    except (OSError, ValueError) as err:
        raise DataError(f"{path}: not a readable m3gd checkpoint") from err
    if meta.get("format") != FORMAT:
        raise DataError(f"{path / STATE}: format {meta.get('format')!r}, expected {FORMAT!r}")
    return tensors, meta


def prefixed(tensors: dict[str, Tensor], prefix: str) -> dict[str, Tensor]:
    """Entries under `prefix.` with the prefix stripped."""
    n = len(prefix) + 1
    return {k[n:]: v for k, v in tensors.items() if k.startswith(prefix + ".")}
