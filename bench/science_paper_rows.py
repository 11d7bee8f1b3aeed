"""The rows of the paper suite (`m3gd bench science --suite paper*`): each a packet mode with
its training regime, loss and time controls (`Variant`), and the named groups of rows the
tables and headline keys are built from."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from model.training_modes import TrainingRegime


@dataclass(frozen=True)
class Variant:
    """One row of the paper suite: packet mode, training mode and the time controls."""

    name: str
    mode: str
    training_mode: str = "scratch"
    init_from: str | None = None  # the variant (same seed) a freeze / finetune run starts from
    loss_views: str = "target"
    lidar_dropout: bool = True
    dtau_channel: bool = True
    data: str = "clean"  # "clean", or "offset": training recordings with a clock offset
    lr: float | None = None  # peak learning rate (None: the spec's)
    anchor: str | None = None  # NetConfig.anchor (None: the spec's)
    loss_space: str = "v"  # TrainConfig.loss_space

    def train_over(self) -> dict[str, Any]:
        """TrainConfig fields of this variant (`TrainingRegime.train_fields`, and lr)."""
        init = None if self.init_from is None else Path(f"{self.init_from} (same seed)")
        regime = TrainingRegime(self.training_mode, init, self.loss_views, self.lidar_dropout,
                                self.loss_space)
        return {**regime.train_fields(), **({} if self.lr is None else {"lr": self.lr})}


PACKET_ROWS = ("full", "geom_only", "zero", "learnable", "no_lidar")
WARP_ROWS = ("warp", "full_warp")
"""The model modes that read the LiDAR reprojection of the source latents (schemas.modes)."""
XLOSS_ROWS = ("warp_x", "no_lidar_x")
"""warp and no_lidar with the loss on the clean latent (TrainConfig.loss_space 'x')."""
ANCHOR_ROWS = ("warp_anchor", "warp_anchor_x")
"""warp, its x-prediction added to the LiDAR reprojection (NetConfig.anchor 'reprojection'):
the untrained network is the reprojection baseline and training learns the residual (eq. 12's
loss, and the loss on the clean latent)."""
EXTRA_ROWS = (*XLOSS_ROWS, *ANCHOR_ROWS)
WARP_TABLE = ("no_lidar", "full", *WARP_ROWS, *XLOSS_ROWS)
"""The rows of the warp table (`m3gd bench science --suite paper-cpu --rows ...`)."""
VARIANTS = (
    *(Variant(m, m) for m in (*PACKET_ROWS, *WARP_ROWS)),
    Variant("warp_x", "warp", loss_space="x"),
    Variant("no_lidar_x", "no_lidar", loss_space="x"),
    Variant("warp_anchor", "warp", anchor="reprojection"),
    Variant("warp_anchor_x", "warp", anchor="reprojection", loss_space="x"),
    Variant("freeze_full", "full", "freeze", "no_lidar"),
    Variant("freeze_no_lidar", "no_lidar", "freeze", "no_lidar"),
    Variant("finetune_full", "full", "finetune", "no_lidar"),
    Variant("finetune_full_lr1e-4", "full", "finetune", "no_lidar", lr=1e-4),
    Variant("full_all_views", "full", loss_views="all"),
    Variant("full_no_dropout", "full", lidar_dropout=False),
    Variant("full_no_dtau", "full", dtau_channel=False),
    Variant("offset_full", "full", data="offset"),
    Variant("offset_full_no_dtau", "full", dtau_channel=False, data="offset"),
)
"""Every row of the suite, in table order."""
