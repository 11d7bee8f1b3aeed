"""Training modes of the paper's Table 5: how a run starts, what it trains, what its loss sees.

- scratch:  every weight from its initialization, every weight trained (the default);
- freeze:   start from a no_lidar checkpoint, train only the adapter (and the learnable
            packet), every backbone weight fixed: the cleanest isolation of what the packets
            add, since the image model is the same for every packet mode;
- finetune: start from a no_lidar checkpoint, train every weight.

Starting from a no_lidar checkpoint, a packet-reading adapter inherits the no_lidar
adapter's weights on the latent and role inputs and gets zero weights on the packet inputs,
so at step 0 it computes exactly the no_lidar network and only training on packets moves it.

Loss views: "target" (eq. 12, target views only) or "all" (every view of the clip, sources
too). LiDAR classifier-free dropout on or off is `TrainConfig.p_lidar` (0.1 or 0).
Everything here is recorded in the checkpoint's `train` JSON (`TrainConfig`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from schemas.errors import DataError

TRAINING_MODES = ("scratch", "freeze", "finetune")
"""How a run starts and what it trains."""
LOSS_VIEWS = ("target", "all")
"""Which views the flow-matching loss scores."""
TRAINABLE_PREFIX = "adapter."
"""Under freeze, the parameters whose name starts so are the only ones trained."""
LIDAR_DROPOUT = 0.1
"""The paper's probability of the null packet per clip when LiDAR dropout is on."""


@dataclass(frozen=True)
class TrainingRegime:
    """What `m3gd train --training-mode ... --init-from ... --loss-views ... --lidar-dropout
    --loss-space` asks for; `train_fields` is how it is recorded in `TrainConfig`."""

    training_mode: str = "scratch"
    init_from: Path | None = None
    loss_views: str = "target"
    lidar_dropout: bool = True
    loss_space: str = "v"

    def check(self) -> None:
        """One-line DataError for an inconsistent request."""
        if self.training_mode not in TRAINING_MODES:
            raise DataError(f"unknown training mode {self.training_mode!r}; one of "
                            f"{TRAINING_MODES}")
        if self.loss_views not in LOSS_VIEWS:
            raise DataError(f"unknown loss views {self.loss_views!r}; one of {LOSS_VIEWS}")
        if self.loss_space not in ("v", "x"):
            raise DataError(f"unknown loss space {self.loss_space!r}; one of ('v', 'x')")
        if (self.training_mode == "scratch") != (self.init_from is None):
            raise DataError(f"training mode {self.training_mode!r} "
                            + ("needs --init-from <no_lidar checkpoint>"
                               if self.init_from is None else "takes no --init-from"))

    def train_fields(self) -> dict[str, Any]:
        """The `TrainConfig` fields of this regime."""
        return {"training_mode": self.training_mode,
                "init_from": None if self.init_from is None else str(self.init_from),
                "loss_views": self.loss_views, "loss_space": self.loss_space,
                "p_lidar": LIDAR_DROPOUT if self.lidar_dropout else 0.0}


def freeze_for(net: nn.Module, training_mode: str) -> None:
    """Under freeze, only parameters named `TRAINABLE_PREFIX`* keep requires_grad."""
    if training_mode not in TRAINING_MODES:
        raise DataError(f"unknown training mode {training_mode!r}; one of {TRAINING_MODES}")
    if training_mode != "freeze":
        return
    for name, p in net.named_parameters():
        p.requires_grad_(name.startswith(TRAINABLE_PREFIX))


def adapted_state(source: dict[str, Tensor], target: dict[str, Tensor], c: int
                  ) -> dict[str, Tensor]:
    """`target`'s state dict filled from `source` (a no_lidar network's state).

    Same name and shape: copied. The adapter's first layer (hidden, C + P + 1) of a packet
    mode takes the source's (hidden, C + 1) columns for the latent (first C) and role (last)
    inputs and zero columns for the P packet inputs. Entries the source lacks (the learnable
    packet) keep the target's values. Any other mismatch is a DataError naming the entry.
    """
    out = dict(target)
    for name, value in target.items():
        if name not in source:
            continue
        src = source[name]
        if src.shape == value.shape:
            out[name] = src.clone()
        elif name == "adapter.conv_in.weight" and src.shape[1] == c + 1 and \
                src.shape[0] == value.shape[0]:
            w = torch.zeros_like(value)
            w[:, :c], w[:, -1] = src[:, :c], src[:, -1]
            out[name] = w
        else:
            raise DataError(f"init checkpoint entry {name}: shape {tuple(src.shape)} does not "
                            f"fit {tuple(value.shape)} (another network size?)")
    return out


def source_net_state(checkpoint: Path) -> tuple[dict[str, Tensor], dict[str, Any]]:
    """The raw network weights and metadata of the checkpoint a freeze/finetune run starts
    from; a DataError unless it is a no_lidar network."""
    from model.checkpoint import load_checkpoint, prefixed

    tensors, meta = load_checkpoint(checkpoint)
    mode = meta["net"]["mode"]
    if mode != "no_lidar":
        raise DataError(f"{checkpoint}: --init-from needs a no_lidar checkpoint (it holds "
                        f"mode {mode!r})")
    return prefixed(tensors, "model"), meta


def check_same_network(source: dict[str, Any], target: dict[str, Any], where: Path) -> None:
    """The source network's sizes match the new one's except the packet mode."""
    keys = [k for k in target if k != "mode" and source.get(k) != target[k]]
    if keys:
        raise DataError(f"{where}: the init checkpoint's network differs in "
                        + ", ".join(f"{k} ({source.get(k)!r} vs {target[k]!r})" for k in keys))


@torch.no_grad()
def start_from(net: nn.Module, ema: nn.Module, checkpoint: Path, c: int,
               net_json: dict[str, Any]) -> None:
    """Load a no_lidar checkpoint's raw weights into `net` and `ema` (`adapted_state`)."""
    state, meta = source_net_state(checkpoint)
    src_json = dict(meta["net"])
    for k, v in net_json.items():  # lists and tuples compare equal as JSON
        if isinstance(v, tuple):
            net_json = {**net_json, k: list(v)}
    check_same_network(src_json, net_json, checkpoint)
    new = adapted_state(state, net.state_dict(), c)
    net.load_state_dict(new)
    ema.load_state_dict(new)


def loss_mask(is_target: Tensor, loss_views: str) -> Tensor:
    """The (B, V) bool mask of views the loss scores."""
    if loss_views == "target":
        return is_target
    if loss_views == "all":
        return torch.ones_like(is_target, dtype=torch.bool)
    raise DataError(f"unknown loss views {loss_views!r}; one of {LOSS_VIEWS}")


COUNT_KEYS = {"target": "_n_targets", "all": "_n_views"}
"""The batch entry holding the global batch's count of scored views (`model.batching`)."""
