"""The packet modes (what of a LiDAR packet reaches the model): the one definition.

- `full`: g (the explicit channels of schemas.channels) and h (C_u point features per cell);
- `geom_only`: g only;
- `zero`: the same adapter pathway fed zeros (capacity without content);
- `learnable`: the same pathway fed one learned, data-independent tensor of the packet's
  shape (capacity that trains, without content: the paper's Table 6 control);
- `no_lidar`: no LiDAR pathway at all;
- `warp`: g, and on target views the source latents reprojected into the target by its
  packet depth and the cameras (`model.reprojection.warp_latents`) with their validity
  (C + 1 channels after g): the network learns a residual on the reprojection;
- `full_warp`: g, h and the same warp channels after h.

The first five are the paper's (and the cache's: `PacketMode`, config `packets.mode`); the
warp modes are model modes (`MODEL_MODES`): their packets are the cache's geom_only / full
packets (`cache_mode`), the warp channels are computed per batch from the clip's latents,
cameras and g, so the cache format is the same.

Each mode is a `PacketModeSpec` that carries its behaviour: the cache arrays a stream reads,
the packet components assembled from a sweep, what the adapter is fed and its packet width.
Code asks the object (`packet_mode(name).feed`, `.reads_h`, `.channels(c_u)`) instead of
comparing names. The names, and so the config, cache and checkpoint formats, are unchanged
(a checkpoint records its mode's name in its network JSON).

Pure names (no I/O): the packets layer may import this module.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

from schemas.channels import n_g
from schemas.errors import DataError

PacketMode = Literal["full", "geom_only", "zero", "learnable", "no_lidar"]
PACKET_MODES: tuple[str, ...] = get_args(PacketMode)
"""Every packet mode of the paper (and of a cache), in the order tables and plots list them."""
WarpMode = Literal["warp", "full_warp"]
WARP_MODES: tuple[str, ...] = get_args(WarpMode)
"""The modes that add reprojected source latents to a target's packet."""
ModelMode = Literal[PacketMode, WarpMode]
MODEL_MODES: tuple[str, ...] = PACKET_MODES + WARP_MODES
"""Every mode a network can be trained in (`m3gd train --mode`), paper modes first."""

Feed = Literal["data", "zeros", "learned", "none"]
"""What the adapter is fed: the recording's packet, zeros of the packet's shape, one learned
tensor, or nothing (no pathway)."""


@dataclass(frozen=True)
class PacketModeSpec:
    """One packet mode and its behaviour.

    arrays: the packet arrays a clip stream reads from the cache ("g", "h");
    feed: what reaches the adapter (`Feed`);
    with_h: the packet carries the C_u feature channels after g (P = n_g + C_u, else n_g);
    reads_h: a sweep's point features are pooled into h (the point encoder runs);
    has_tensor: a packet assembled from a sweep holds g (and h) arrays at all;
    warp: target views gain C + 1 channels after g (and h): the clip's source latents
    reprojected into the target (C, normalized like the latents) and their validity (1).
    """

    name: str
    arrays: tuple[str, ...]
    feed: Feed
    with_h: bool
    warp: bool = False

    @property
    def reads_h(self) -> bool:
        """The point features are read (the mode's packets carry real h)."""
        return "h" in self.arrays

    @property
    def has_tensor(self) -> bool:
        """A packet assembled from a sweep carries g and h arrays (zeros for 'zero')."""
        return self.feed in ("data", "zeros")

    @property
    def cache_mode(self) -> str:
        """The paper mode whose packets the cache must hold for this mode (`PacketMode`)."""
        if not self.warp:
            return self.name
        return "full" if self.with_h else "geom_only"

    def channels(self, c_u: int, c: int | None = None) -> int:
        """Number of packet channels P the adapter sees: 0 without a pathway, else the
        explicit channels (schemas.channels.n_g()) plus C_u when the packet carries h, plus
        C + 1 (latent channels C, a DataError without it) for the warp."""
        if self.feed == "none":
            return 0
        if self.warp and c is None:
            raise DataError(f"packet mode {self.name!r}: the width needs the latent channels C")
        return n_g() + (c_u if self.with_h else 0) + (c + 1 if self.warp and c is not None else 0)


MODE_SPECS: dict[str, PacketModeSpec] = {m.name: m for m in (
    PacketModeSpec("full", ("g", "h"), "data", with_h=True),
    PacketModeSpec("geom_only", ("g",), "data", with_h=False),
    PacketModeSpec("zero", (), "zeros", with_h=True),
    PacketModeSpec("learnable", (), "learned", with_h=True),
    PacketModeSpec("no_lidar", (), "none", with_h=False),
    PacketModeSpec("warp", ("g",), "data", with_h=False, warp=True),
    PacketModeSpec("full_warp", ("g", "h"), "data", with_h=True, warp=True),
)}
"""Every mode's behaviour, by name, in `MODEL_MODES` order."""

MODE_ARRAYS: dict[str, tuple[str, ...]] = {name: m.arrays for name, m in MODE_SPECS.items()}
"""The packet arrays a stream reads from the cache for each mode."""


def packet_mode(name: str) -> PacketModeSpec:
    """The mode called `name`; a one-line DataError naming the modes for any other."""
    try:
        return MODE_SPECS[name]
    except (KeyError, TypeError):
        raise DataError(f"unknown packet mode {name!r}; one of {MODEL_MODES}") from None
