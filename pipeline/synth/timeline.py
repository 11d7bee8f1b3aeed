"""Sensor stamps of a recording (int64 ns): LiDAR sweep starts, jittered camera stamps, odometry.

t0 is the first sweep's start. Cameras start `camera_lead_s` before the LiDAR (so the first
images have no sweep within 0.1 s) and each camera has its own offset to the LiDAR clock plus
Gaussian jitter, so the nearest-sweep offset Delta-tau spreads over about +-50 ms. Odometry runs
from a second before the first sensor to a second after the last one.

`camera_ns` are true capture times (what is rendered). A camera clock offset (cfg
`camera_clock_offset_s`, default 0) is what a badly synchronized camera clock does: the images'
header stamps and bag times read capture time + offset (`Timeline.camera_clock`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from schemas.config import SynthConfig

I64 = npt.NDArray[np.int64]
T0_NS = 1_717_000_000_000_000_000  # 2024-05-29T16:26:40Z, a GrandTour-era epoch
NS = 1_000_000_000


@dataclass(frozen=True)
class Timeline:
    """All nominal stamps (ns) of one recording; camera stamps per camera name."""

    t0_ns: int
    sweep_start_ns: I64
    sweep_period_ns: int
    camera_ns: dict[str, I64]
    camera_offset_ns: dict[str, int]
    odom_ns: I64
    clock_offset_ns: int = 0

    def camera_clock(self, capture_ns: int) -> int:
        """The stamp a camera writes for an image captured at `capture_ns` (LiDAR clock, ns)."""
        return capture_ns + self.clock_offset_ns

    @property
    def end_ns(self) -> int:
        """End of the last sweep (ns)."""
        return (
            int(self.sweep_start_ns[-1]) + self.sweep_period_ns
            if self.sweep_start_ns.size
            else self.t0_ns
        )


def make_timeline(cfg: SynthConfig, cameras: list[str], rng: np.random.Generator) -> Timeline:
    """Stamps for `cfg.seconds` of recording (deterministic in rng)."""
    t0 = T0_NS
    period = round(NS / cfg.lidar_hz)
    n_sweeps = max(1, round(cfg.seconds * cfg.lidar_hz))
    jitter = rng.integers(-50_000, 50_001, n_sweeps)  # +-50 us spin jitter
    sweeps = t0 + np.arange(n_sweeps, dtype=np.int64) * period + jitter
    sweeps[0] = t0
    lead = round(cfg.camera_lead_s * NS)
    cam_period = round(NS / cfg.camera_hz)
    n_cam = max(1, round((cfg.seconds + cfg.camera_lead_s) * cfg.camera_hz))
    sigma = cfg.camera_jitter_ms * 1e6
    camera_ns, offsets = {}, {}
    for cam in cameras:
        offsets[cam] = int(rng.integers(-35_000_000, 35_000_001))
        jit = np.clip(rng.normal(0.0, sigma, n_cam), -3 * sigma, 3 * sigma).round().astype(np.int64)
        camera_ns[cam] = (
            t0 - lead + offsets[cam] + np.arange(n_cam, dtype=np.int64) * cam_period + jit
        )
    odom_period = round(NS / cfg.odom_hz)
    first = t0 - lead - NS
    n_odom = int((t0 + n_sweeps * period + NS - first) // odom_period) + 1
    odom = first + np.arange(n_odom, dtype=np.int64) * odom_period
    clock = round(cfg.camera_clock_offset_s * NS)
    return Timeline(t0, sweeps.astype(np.int64), period, camera_ns, offsets, odom, clock)
