"""Plausibility of odometry poses (pure): unit quaternions and no jumps between neighbours.

A flipped byte in a pose's float64 values gives a finite, plausible-looking number. Two things
a real odometry stream guarantees catch most such flips:

- its quaternions are normalized (to ~1e-9; `quat_norm_problem` refuses a norm off by more
  than the tolerance instead of silently re-normalizing it);
- the robot moves at a bounded speed: `JumpFilter` judges each pose against up to `WINDOW`
  neighbours on each side (in reading order, one stream) and refuses it when it is farther
  from most of them than `max_speed_m_s` times their time apart (plus `SLACK_M`). A damaged
  pose disagrees with all its neighbours; a good neighbour of a damaged pose still agrees with
  its other neighbours, so it is kept. Lookahead: `WINDOW` poses.

Not caught: a flip in the low mantissa bytes of a position (sub-millimetre) or a quaternion
component (below the norm tolerance).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
WINDOW = 2
"""Neighbours on each side a pose is judged against."""
SLACK_M = 0.01
"""Distance (m) any two poses may differ by regardless of time (estimator noise)."""


def quat_norm_problem(quat: F64, tol: float) -> str | None:
    """One line when the quaternion (4,) is not of unit norm within `tol`, else None."""
    norm = float(np.linalg.norm(quat))
    if abs(norm - 1.0) <= tol:
        return None
    return (f"quaternion {quat.tolist()} has norm {norm:.12g}, not 1 within {tol:g}: "
            "a corrupt pose")  # fmt: skip


@dataclass(frozen=True)
class PoseVerdict:
    """A judged pose: stamp (ns), position (3,) m, its payload, and a detail when refused."""

    stamp_ns: int
    position: F64
    item: Any
    problem: str | None = None


class JumpFilter:
    """Refuses poses that jump away from their neighbours (see the module docstring)."""

    def __init__(self, max_speed_m_s: float) -> None:
        """Nothing seen yet; `max_speed_m_s` bounds the speed between two good poses."""
        self.max_speed = max_speed_m_s
        self._poses: deque[tuple[int, F64, Any]] = deque()
        self._judged = 0  # poses of `_poses` already judged (the ones kept as past neighbours)

    def push(self, stamp_ns: int, position: F64, item: Any) -> list[PoseVerdict]:
        """Take the next pose; verdicts on the poses that now have their full lookahead."""
        self._poses.append((stamp_ns, np.asarray(position, dtype=np.float64), item))
        out = []
        while len(self._poses) - self._judged > WINDOW:
            out.append(self._judge(self._judged))
            self._advance()
        return out

    def flush(self) -> list[PoseVerdict]:
        """Verdicts on every pose not yet judged (the end of the stream); then empty."""
        out = []
        while self._judged < len(self._poses):
            out.append(self._judge(self._judged))
            self._advance()
        self._poses.clear()
        self._judged = 0
        return out

    def _advance(self) -> None:
        """Mark one more pose judged; forget poses older than the window."""
        self._judged += 1
        if self._judged > WINDOW:
            self._poses.popleft()
            self._judged -= 1

    def _judge(self, i: int) -> PoseVerdict:
        """Verdict on pose `i` of the window against its neighbours."""
        stamp, pos, item = self._poses[i]
        others = [p for j, p in enumerate(self._poses) if j != i]
        far = [(s, float(np.linalg.norm(pos - q)), (abs(s - stamp) / 1e9)) for s, q, _ in others]
        jumps = [(s, d, dt) for s, d, dt in far if d > self.max_speed * dt + SLACK_M]
        if not others or 2 * len(jumps) <= len(others):
            return PoseVerdict(stamp, pos, item)
        s, d, dt = jumps[0]
        detail = (f"position {pos.tolist()} m is {d:.3f} m from {len(jumps)} of its "
                  f"{len(others)} neighbours (e.g. the pose at {s} ns, {dt:.3f} s away): faster "
                  f"than {self.max_speed:g} m/s, a corrupt pose")  # fmt: skip
        return PoseVerdict(stamp, pos, item, detail)
