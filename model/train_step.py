"""One training step of M3GD: target-only flow matching with CFG dropout, AdamW, EMA.

A batch is a dict of tensors:
  latents      (B, V, C, H, W) float32  normalized level-0 latents z_0 of all views
  g            (B, V, 6, H, W) float32  explicit statistics (absent in 'zero'/'no_lidar')
  h            (B, V, H, W, C_u)        pooled descriptors, channels-last (only 'full')
  K            (B, V, 3, 3)             intrinsics in pixels of the NetConfig.image_hw image
  T_world_cam  (B, V, 4, 4)             camera poses, metres
  is_target    (B, V) bool              role r_v
Optional entries written by the data plan (`model.batching`):
  _pos         (B,) int64  position of each clip in its global batch (randomness seed)
  _weight      (B,) float  1, or 0 for a padding clip that only keeps ranks in step
  _n_targets   ()   int64  target views of the whole global batch (the loss's denominator)
  _n_views     ()   int64  views of the whole global batch (the all-views loss's denominator)
Randomness (t, z_1, dropout masks) of a clip is drawn from a generator seeded by (seed,
update number, position in the global batch) (`model.flow.sample_seed`): a resumed run
repeats the uninterrupted one exactly, and a global batch split over R ranks and A
gradient-accumulation micro-batches takes the same update as one process with all of it.

Device and precision: the network lives on `device`; the forward runs under autocast to
`precision` (bf16 / fp16) on that device, with a GradScaler for fp16; the draws are made on
the CPU and copied, so every device sees the same numbers. Several processes
(torch.distributed, `model.distributed`) wrap the network in DistributedDataParallel.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor
from torch.nn.parallel import DistributedDataParallel

from model.checkpoint import (
    flatten_optimizer,
    load_checkpoint,
    prefixed,
    save_checkpoint,
    unflatten_optimizer,
)
from model.device import autocast, check_precision, grad_scaler, to_device
from model.distributed import DistInfo, all_sum
from model.flow import interpolate, per_sample_draws, sample_seed, target_sq_error
from model.net import M3GDNet, NetConfig
from model.training_modes import COUNT_KEYS, freeze_for, loss_mask
from schemas.errors import DataError, M3GDError


@dataclass(frozen=True)
class TrainConfig:
    """Optimization settings (paper: AdamW, lr 5e-5 constant, EMA 0.9995, dropout 0.1 each)."""

    lr: float = 5e-5
    weight_decay: float = 0.0
    ema_decay: float = 0.9995
    p_cam: float = 0.1
    p_lidar: float = 0.1
    bf16: bool = False  # older spelling of precision="bf16" (checkpoints keep it)
    precision: str = "fp32"  # fp32 | bf16 | fp16 (model.device.PRECISIONS)
    grad_accum: int = 1  # micro-batches per update (global batch = batch x ranks x this)
    grad_clip: float | None = 1.0
    seed: int = 0
    t_sampling: str = "uniform"  # or "logit_normal" (model.flow.sample_t)
    t_mu: float = 0.0
    t_sigma: float = 1.0
    warmup_steps: int = 0  # linear warm-up from 0 to lr
    decay_steps: int = 0  # cosine decay to lr_min over this many steps after warm-up (0: none)
    lr_min: float = 0.0
    training_mode: str = "scratch"  # scratch | freeze | finetune (model.training_modes)
    init_from: str | None = None  # the no_lidar checkpoint a freeze / finetune run started from
    loss_views: str = "target"  # target | all: the views the loss scores
    loss_space: str = "v"  # v: eq. 12 on the velocity | x: on the clean latent, t^2 (v - u)^2

    def __post_init__(self) -> None:
        if self.loss_space not in ("v", "x"):
            raise DataError(f"loss_space must be 'v' or 'x', got {self.loss_space!r}")

    @property
    def compute_precision(self) -> str:
        """The effective precision (bf16=True reads as precision bf16)."""
        return "bf16" if self.bf16 and self.precision == "fp32" else self.precision

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
    """Network, EMA copy, AdamW (and loss scaler) on a device; `step(batch)` does one update.

    device: where the network runs (CPU by default); compile: torch.compile the backbone
    in place (state-dict keys unchanged); dist: this process's rank in a multi-process run.
    """

    def __init__(self, net_cfg: NetConfig, cfg: TrainConfig, device: torch.device | None = None,
                 compile: bool = False, dist: DistInfo | None = None) -> None:
        self.net_cfg, self.cfg = net_cfg, cfg
        self.device = device or torch.device("cpu")
        self.dist = dist or DistInfo()
        self.precision = check_precision(cfg.compute_precision)
        with torch.random.fork_rng(devices=[]):  # deterministic init, global RNG untouched
            torch.manual_seed(cfg.seed)
            self.net = M3GDNet(net_cfg)  # built on the CPU: the same weights on every device
        self.net.to(self.device)
        freeze_for(self.net, cfg.training_mode)  # freeze: only the adapter trains
        self.ema = copy.deepcopy(self.net).requires_grad_(False).eval()
        if compile:
            self.net.backbone.compile()
        self.model: torch.nn.Module = self.net
        if self.dist.active:
            ids = [self.device.index] if self.device.type == "cuda" else None
            self.model = DistributedDataParallel(self.net, device_ids=ids)
        self.opt = torch.optim.AdamW(self.net.parameters(), lr=cfg.lr,
                                     weight_decay=cfg.weight_decay)
        self.scaler = grad_scaler(self.device, self.precision)
        self.step_count = 0
        self.skipped = 0  # fp16 updates the scaler skipped (gradient overflow)
        self.last_grad_norm = math.nan
        self.extra: dict[str, Any] = {}  # JSON carried through checkpoints (loader state)

    def loss(self, batch: dict[str, Tensor]) -> Tensor:
        """Loss of one (micro-)batch (on the trainer's device) as its share of the global
        batch: squared error over its target entries / target entries of the global batch,
        times the ranks (DistributedDataParallel averages gradients over ranks)."""
        z_0 = batch["latents"].float()  # (B, V, C, H, W)
        B = z_0.shape[0]
        pos = batch["_pos"].tolist() if "_pos" in batch else list(range(B))
        c = self.cfg
        seeds = [sample_seed(c.seed, self.step_count, p) for p in pos]
        t, z_1, drop_cam, drop_lidar = (x.to(self.device) for x in per_sample_draws(
            tuple(z_0.shape[1:]), seeds, c.t_sampling, c.t_mu, c.t_sigma, c.p_cam, c.p_lidar))
        z_t, u = interpolate(z_0, z_1, t), z_1 - z_0
        with autocast(self.device, self.precision):
            v = self.model(batch, z_t, t, drop_cam, drop_lidar)  # (B, V, C, H, W)
        scored = loss_mask(batch["is_target"], c.loss_views)  # (B, V): targets or all views
        count = COUNT_KEYS[c.loss_views]
        n_tgt = batch[count] if count in batch else scored.sum()
        denom = float(n_tgt) * z_0[0, 0].numel()
        if denom == 0:
            raise DataError("target-only loss: the global batch has no target view")
        if c.loss_space == "x":  # z0_hat - z_0 = -t (v - u) on the linear path
            t_ = t.to(v.dtype)[:, None, None, None, None]
            v, u = v * t_, u * t_
        sq = target_sq_error(v, u, scored, batch.get("_weight"))
        return sq * (self.dist.world_size / denom)

    def step(self, batch: dict[str, Tensor] | Sequence[dict[str, Tensor]]) -> float:
        """One update from a batch or its gradient-accumulation micro-batches; the loss.

        Raises `DivergedError` on a non-finite loss or gradient norm, before any update, so
        the network, EMA and optimizer keep their last finite state (every rank raises: the
        loss and the norm are reduced over ranks first). Under fp16 a gradient overflow is
        the scaler's business: that update is skipped and the scale lowered.
        """
        micro = [batch] if isinstance(batch, dict) else list(batch)
        self.net.train()
        self.opt.zero_grad(set_to_none=True)
        total = torch.zeros((), device=self.device)
        for i, mb in enumerate(micro):
            last = i == len(micro) - 1
            sync = nullcontext() if last or not self.dist.active else self._no_sync()
            with sync:
                loss = self.loss(to_device(mb, self.device))
                torch.autograd.backward(self.scaler.scale(loss))
            total += loss.detach()
        loss_all = float(all_sum(total)) / self.dist.world_size
        if not math.isfinite(loss_all):
            self.opt.zero_grad(set_to_none=True)
            raise DivergedError(self.step_count, "loss", loss_all)
        self._update()
        return loss_all

    def _no_sync(self) -> Any:
        """DistributedDataParallel's no_sync(): gradients stay local until the last micro-batch."""
        assert isinstance(self.model, DistributedDataParallel)
        return self.model.no_sync()

    def _update(self) -> None:
        """Clip, optimizer step (through the scaler), EMA; counts the update."""
        self.scaler.unscale_(self.opt)
        clip = math.inf if self.cfg.grad_clip is None else self.cfg.grad_clip
        norm = torch.nn.utils.clip_grad_norm_(self.net.parameters(), clip)
        self.last_grad_norm = float(norm)
        if not math.isfinite(self.last_grad_norm) and not self.scaler.is_enabled():
            self.opt.zero_grad(set_to_none=True)
            raise DivergedError(self.step_count, "gradient norm", self.last_grad_norm)
        for group in self.opt.param_groups:
            group["lr"] = self.cfg.lr_at(self.step_count)
        scale = self.scaler.get_scale() if self.scaler.is_enabled() else 1.0
        self.scaler.step(self.opt)  # skipped by the scaler on an fp16 overflow
        self.scaler.update()
        if self.scaler.is_enabled() and self.scaler.get_scale() < scale:
            self.skipped += 1
        self.update_ema()
        self.step_count += 1

    @torch.no_grad()
    def update_ema(self) -> None:
        """ema <- decay * ema + (1 - decay) * weights."""
        for e, p in zip(self.ema.parameters(), self.net.parameters(), strict=True):
            e.lerp_(p, 1.0 - self.cfg.ema_decay)

    def state(self, extra: dict[str, Any] | None = None
              ) -> tuple[dict[str, Tensor], dict[str, Any]]:
        """(tensors on the CPU, JSON state) of a checkpoint; `extra`: JSON (loader state).

        Refuses (DivergedError) non-finite weights.
        """
        for name, p in self.net.named_parameters():
            if not torch.isfinite(p).all():
                raise DivergedError(self.step_count, f"weight {name}", float("nan"))
        opt_tensors, opt_meta = flatten_optimizer(self.opt)
        tensors = {**{f"model.{k}": v for k, v in self.net.state_dict().items()},
                   **{f"ema.{k}": v for k, v in self.ema.state_dict().items()},
                   **opt_tensors}
        meta = {"step": self.step_count, "net": self.net_cfg.to_json(),
                "train": asdict(self.cfg), "extra": extra or {}, "skipped": self.skipped,
                "scaler": self.scaler.state_dict(), **opt_meta}
        return {k: v.detach().cpu() for k, v in tensors.items()}, meta

    def save(self, path: Path, extra: dict[str, Any] | None = None) -> None:
        """Checkpoint file in directory `path` (safetensors, the state in its header, no
        pickle), written atomically (`model.checkpoint`); `extra`: JSON (loader state).

        Refuses (DivergedError) to write non-finite weights over a saved state.
        """
        save_checkpoint(path, *self.state(extra))

    @classmethod
    def load(cls, path: Path, device: torch.device | None = None, compile: bool = False,
             dist: DistInfo | None = None) -> Trainer:
        """Rebuild a trainer from `save()` output on `device`, ready to continue exactly."""
        tensors, meta = load_checkpoint(path)
        trainer = cls(NetConfig.from_json(meta["net"]), TrainConfig(**meta["train"]), device,
                      compile, dist)
        trainer.net.load_state_dict(prefixed(tensors, "model"))
        trainer.ema.load_state_dict(prefixed(tensors, "ema"))
        trainer.opt.load_state_dict(unflatten_optimizer(tensors, meta))
        if meta.get("scaler"):
            trainer.scaler.load_state_dict(meta["scaler"])
        trainer.step_count = int(meta["step"])
        trainer.skipped = int(meta.get("skipped", 0))
        trainer.extra = dict(meta.get("extra", {}))
        return trainer
