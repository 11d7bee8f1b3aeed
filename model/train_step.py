"""One training step of M3GD: target-only flow matching with CFG dropout, AdamW, EMA.

A batch is a dict of tensors:
  latents      (B, V, C, H, W) float32  normalized level-0 latents z_0 of all views
  g            (B, V, 6, H, W) float32  explicit statistics (absent in 'zero'/'no_lidar')
  h            (B, V, H, W, C_u)        pooled descriptors, channels-last (only 'full')
  K            (B, V, 3, 3)             intrinsics in pixels of the NetConfig.image_hw image
  T_world_cam  (B, V, 4, 4)             camera poses, metres
  is_target    (B, V) bool              role r_v
All randomness (t, z_1, dropout masks) comes from the trainer's own generator, which is
checkpointed, so a resumed run repeats the uninterrupted one exactly.
"""

from __future__ import annotations

import copy
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from model.checkpoint import (
    flatten_optimizer,
    load_checkpoint,
    prefixed,
    save_checkpoint,
    unflatten_optimizer,
)
from model.flow import sample_dropout, sample_path, target_only_loss
from model.net import M3GDNet, NetConfig
from schemas.errors import M3GDError


@dataclass(frozen=True)
class TrainConfig:
    """Optimization settings (paper: AdamW, lr 5e-5 constant, EMA 0.9995, dropout 0.1 each)."""

    lr: float = 5e-5
    weight_decay: float = 0.0
    ema_decay: float = 0.9995
    p_cam: float = 0.1
    p_lidar: float = 0.1
    bf16: bool = False
    grad_clip: float | None = 1.0
    seed: int = 0
    t_sampling: str = "uniform"  # or "logit_normal" (model.flow.sample_t)
    t_mu: float = 0.0
    t_sigma: float = 1.0
    warmup_steps: int = 0  # linear warm-up from 0 to lr
    decay_steps: int = 0  # cosine decay to lr_min over this many steps after warm-up (0: none)
    lr_min: float = 0.0

    def lr_at(self, step: int) -> float:
        """Learning rate of update number `step` (0-based): warm-up, then cosine or constant."""
        if step < self.warmup_steps:
            return self.lr * (step + 1) / self.warmup_steps
        if self.decay_steps <= 0:
            return self.lr
        frac = min(1.0, (step - self.warmup_steps) / self.decay_steps)
        return self.lr_min + 0.5 * (self.lr - self.lr_min) * (1.0 + math.cos(math.pi * frac))


class DivergedError(M3GDError, FloatingPointError):
    """A non-finite loss or gradient: nothing was updated, the weights are the last finite."""

    def __init__(self, step: int, what: str, value: float) -> None:
        super().__init__(f"training diverged at step {step}: non-finite {what} ({value})")
        self.step, self.what, self.value = step, what, value

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled by its fields (the constructor does not take the message)."""
        return (type(self), (self.step, self.what, self.value))


class Trainer:
    """Network, EMA copy, AdamW and generator; `step(batch)` does one update."""

    def __init__(self, net_cfg: NetConfig, cfg: TrainConfig) -> None:
        self.net_cfg, self.cfg = net_cfg, cfg
        with torch.random.fork_rng():  # deterministic init without touching the global RNG
            torch.manual_seed(cfg.seed)
            self.net = M3GDNet(net_cfg)
        self.ema = copy.deepcopy(self.net).requires_grad_(False).eval()
        self.opt = torch.optim.AdamW(self.net.parameters(), lr=cfg.lr,
                                     weight_decay=cfg.weight_decay)
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.step_count = 0
        self.extra: dict[str, Any] = {}  # JSON carried through checkpoints (loader state)

    def loss(self, batch: dict[str, Tensor]) -> Tensor:
        """Target-only flow-matching loss of one batch (draws t, z_1 and dropout masks)."""
        z_0 = batch["latents"].float()  # (B, V, C, H, W)
        c = self.cfg
        t, z_t, u = sample_path(z_0, self.gen, c.t_sampling, c.t_mu, c.t_sigma)
        drop_cam, drop_lidar = sample_dropout(z_0.shape[0], self.cfg.p_cam, self.cfg.p_lidar,
                                              self.gen)
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=self.cfg.bf16):
            cond = self.net.condition(batch, drop_cam, drop_lidar)
            v = self.net.velocity(z_t, t, cond)  # (B, V, C, H, W)
        return target_only_loss(v, u, batch["is_target"])

    def step(self, batch: dict[str, Tensor]) -> float:
        """One AdamW update and EMA update; returns the loss.

        Raises `DivergedError` on a non-finite loss or gradient norm, before any update, so
        the network, EMA and optimizer keep their last finite state.
        """
        self.net.train()
        loss = self.loss(batch)
        if not torch.isfinite(loss):
            raise DivergedError(self.step_count, "loss", float(loss.item()))
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        clip = math.inf if self.cfg.grad_clip is None else self.cfg.grad_clip
        norm = torch.nn.utils.clip_grad_norm_(self.net.parameters(), clip)
        if not torch.isfinite(norm):
            self.opt.zero_grad(set_to_none=True)
            raise DivergedError(self.step_count, "gradient norm", float(norm))
        for group in self.opt.param_groups:
            group["lr"] = self.cfg.lr_at(self.step_count)
        self.opt.step()
        self.update_ema()
        self.step_count += 1
        return float(loss.item())

    @torch.no_grad()
    def update_ema(self) -> None:
        """ema <- decay * ema + (1 - decay) * weights."""
        for e, p in zip(self.ema.parameters(), self.net.parameters(), strict=True):
            e.lerp_(p, 1.0 - self.cfg.ema_decay)

    def save(self, path: Path, extra: dict[str, Any] | None = None) -> None:
        """Checkpoint directory (safetensors + JSON, no pickle); `extra`: JSON (loader state).

        Refuses (DivergedError) to write non-finite weights over a saved state.
        """
        for name, p in self.net.named_parameters():
            if not torch.isfinite(p).all():
                raise DivergedError(self.step_count, f"weight {name}", float("nan"))
        opt_tensors, opt_meta = flatten_optimizer(self.opt)
        tensors = {**{f"model.{k}": v for k, v in self.net.state_dict().items()},
                   **{f"ema.{k}": v for k, v in self.ema.state_dict().items()},
                   **opt_tensors, "rng.generator": self.gen.get_state()}
        meta = {"step": self.step_count, "net": self.net_cfg.to_json(),
                "train": asdict(self.cfg), "extra": extra or {}, **opt_meta}
        save_checkpoint(path, tensors, meta)

    @classmethod
    def load(cls, path: Path) -> Trainer:
        """Rebuild a trainer from `save()` output, ready to continue exactly."""
        tensors, meta = load_checkpoint(path)
        trainer = cls(NetConfig.from_json(meta["net"]), TrainConfig(**meta["train"]))
        trainer.net.load_state_dict(prefixed(tensors, "model"))
        trainer.ema.load_state_dict(prefixed(tensors, "ema"))
        trainer.opt.load_state_dict(unflatten_optimizer(tensors, meta))
        trainer.gen.set_state(tensors["rng.generator"])
        trainer.step_count = int(meta["step"])
        trainer.extra = dict(meta.get("extra", {}))
        return trainer
