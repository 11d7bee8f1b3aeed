"""The explicit packet channels g (paper eq. 9; SPEC "Explicit statistics"): the one table.

Every producer and consumer of g derives from `PACKET_CHANNELS`: the packet statistics
(`packets.statistics.explicit_channels` computes one formula per row, in table order), the
cache's g array shape (`schemas.cache_layout.packet_arrays`), the occupancy test of the
packed features (`schemas.packed_cells`), the model's channel counts (`model.adapter`), the
viewer's images (`pipeline.analysis.view.scene`) and the cache reference page
(`docs_gen.cache_ref`). Counts and indices are read from the table when called
(`n_g()`, `channel_index(name)`), so a table with one more row is followed everywhere.

Adding a channel: a row here and its formula in `packets/statistics.py` (`FORMULAS`); the
g array's shape changes with it, so bump `schemas.cache_layout.CACHE_FORMAT_VERSION`.

Pure names (no I/O): every layer may import this module.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PacketChannel:
    """One explicit channel of g: its name, unit, value on an occupied cell and source.

    Empty cells (n_q = 0) are zero in every channel (eq. 9). `unit` and `meaning` are the
    text of the cache reference page (docs_gen.cache_ref).
    """

    name: str
    unit: str
    meaning: str
    """The value on an occupied cell (n_q >= 1 support points of mean depth d, metres)."""
    ref: str = "paper eq. 9; SPEC.md 'Explicit statistics'"


PACKET_CHANNELS: tuple[PacketChannel, ...] = (
    PacketChannel("validity", "–", "1 on a cell with LiDAR support (n ≥ 1), 0 elsewhere"),
    PacketChannel("log1p_mean_depth", "log m", "log(1 + mean depth)"),
    PacketChannel("inv_mean_depth", "1/m", "1 / mean depth"),
    PacketChannel("log1p_count", "–", "log(1 + n), n the number of supporting points"),
    PacketChannel("depth_variance", "m²", "variance of the supporting points' depths"),
    PacketChannel("delta_tau_s", "s", "the view's Δτ (the same in every occupied cell); with "
                  "several LiDARs merged, the mean Δτ of the cell's pooled points, each "
                  "point's that of its own sweep"),
)
"""The channels of g (N, n_g(), H, W), in storage order (eq. 9: [1, log(1+d), 1/d,
log(1+n), Var d, Δτ]); depth variance is the population variance (ddof = 0)."""

VALIDITY = "validity"
"""The channel that says a cell is occupied (1.0) or empty (0.0)."""
LOG1P_MEAN_DEPTH = "log1p_mean_depth"
INV_MEAN_DEPTH = "inv_mean_depth"
DELTA_TAU = "delta_tau_s"
"""The channel the model's delta-tau ablation zeroes."""


def channel_names() -> tuple[str, ...]:
    """Names of g's channels in storage order."""
    return tuple(c.name for c in PACKET_CHANNELS)


def n_g() -> int:
    """Number of explicit channels of g (6 for the eq. 9 table)."""
    return len(PACKET_CHANNELS)


def channel_index(name: str) -> int:
    """Index of channel `name` on g's channel axis; KeyError naming the known channels."""
    names = channel_names()
    if name not in names:
        raise KeyError(f"no packet channel {name!r}; channels are {', '.join(names)}")
    return names.index(name)


CHANNELS: tuple[str, ...] = channel_names()
"""Import-time snapshot of `channel_names()` (the old `packets.statistics.CHANNELS`)."""
N_G: int = n_g()
"""Import-time snapshot of `n_g()`; code that must follow an edited table calls `n_g()`."""
