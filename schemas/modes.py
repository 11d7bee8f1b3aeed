"""The packet modes (what of a LiDAR packet reaches the model): the one definition.

- `full`: g (6 geometry channels) and h (C_u point features per cell);
- `geom_only`: g only;
- `zero`: the same adapter pathway fed zeros (capacity without content);
- `learnable`: the same pathway fed one learned, data-independent tensor of the packet's
  shape (capacity that trains, without content: the paper's Table 6 control);
- `no_lidar`: no LiDAR pathway at all.

Pure names (no I/O): the packets layer may import this module.
"""

from __future__ import annotations

from typing import Literal, get_args

PacketMode = Literal["full", "geom_only", "zero", "learnable", "no_lidar"]
PACKET_MODES: tuple[str, ...] = get_args(PacketMode)
"""Every packet mode, in the order tables and plots list them."""
MODE_ARRAYS: dict[str, tuple[str, ...]] = {
    "full": ("g", "h"), "geom_only": ("g",), "zero": (), "learnable": (), "no_lidar": ()}
"""The packet arrays a stream reads from the cache for each mode."""
