"""Plausibility of odometry poses (pure): unit quaternions and no jumps between neighbours.

A flipped byte in a pose's float64 values gives a finite, plausible-looking number. Two things
a real odometry stream guarantees catch most such flips:

- its quaternions are normalized (to ~1e-9; `quat_norm_problem` refuses a norm off by more
  than the tolerance instead of silently re-normalizing it);
- the robot moves at a bounded speed: two poses are consistent when they are no farther apart
  than `max_speed_m_s` times their time apart (plus `SLACK_M`). `JumpFilter` looks at the
  2 * `WINDOW` + 1 poses around each pose (in reading order, one stream; at its ends the
  nearest ones) and keeps the pose when it belongs to a largest pairwise-consistent subset of
  them. A damaged pose (or two in a row) disagrees with the good ones around it, which agree
  with each other, so good neighbours are kept. Lookahead: up to 2 * `WINDOW` poses. A jump
  must exceed about the speed limit times two frame periods to be seen.

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

POSE_CHECKS = ("quat_norm", "pose_jump")
"""The pose stream's fitted checks, in the checks table's order."""


def quat_norm_problem(quat: F64, tol: float) -> str | None:
    """One line when the quaternion (4,) is not of unit norm within `tol`, else None."""
    with np.errstate(over="ignore"):  # a flipped exponent: inf, refused below
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
        self._poses: deque[tuple[int, F64, Any, bool]] = deque()
        self._next = 0  # index in `_poses` of the next pose to judge

    def push(self, stamp_ns: int, position: F64, item: Any,
             judge: bool = True) -> list[PoseVerdict]:  # fmt: skip
        """Take the next pose; verdicts on the poses that now have their full window.

        A pose pushed with `judge` False (a checksum vouches for it) is a neighbour of the
        others and handed on in order, but not judged itself (its verdict has no problem)."""
        self._poses.append((stamp_ns, np.asarray(position, dtype=np.float64), item, judge))
        out = []
        while (len(self._poses) >= 2 * WINDOW + 1
               and len(self._poses) - 1 - self._next >= WINDOW):  # fmt: skip
            out.append(self._judge(self._next))
            self._advance()
        return out

    def flush(self) -> list[PoseVerdict]:
        """Verdicts on every pose not yet judged (the end of the stream); then empty."""
        out = []
        while self._next < len(self._poses):
            out.append(self._judge(self._next))
            self._next += 1
        self._poses.clear()
        self._next = 0
        return out

    def _advance(self) -> None:
        """One more pose judged; keep WINDOW judged poses before the next as its neighbours."""
        self._next += 1
        if self._next > WINDOW:
            self._poses.popleft()
            self._next -= 1

    def _judge(self, i: int) -> PoseVerdict:
        """Verdict on pose `i`: kept when it belongs to a largest mutually consistent subset
        of the 2 * WINDOW + 1 poses around it (as centred as the stream allows)."""
        stamp, here, item, judge = self._poses[i]
        if not judge:
            return PoseVerdict(stamp, here, item)
        size = 2 * WINDOW + 1
        lo = max(0, min(i - WINDOW, len(self._poses) - size))
        window = list(self._poses)[lo : lo + size]
        stamps = np.array([p[0] for p in window], dtype=np.int64)
        pos = np.stack([p[1] for p in window])
        dist = np.linalg.norm(pos[:, None] - pos[None], axis=2)
        dt = np.abs(stamps[:, None] - stamps[None]).astype(np.float64) / 1e9
        ok = dist <= self.max_speed * dt + SLACK_M
        if ok.all() or i - lo in largest_consistent(ok):
            return PoseVerdict(stamp, here, item)
        far = [(int(stamps[k]), float(dist[i - lo, k]), float(dt[i - lo, k]))
               for k in np.flatnonzero(~ok[i - lo])]  # fmt: skip
        s, d, gap = far[0]
        detail = (f"position {here.tolist()} m is {d:.3f} m from the pose at {s} ns, {gap:.3f} s "
                  f"away (and from {len(far) - 1} more of its {len(window) - 1} neighbours): "
                  f"faster than {self.max_speed:g} m/s, a corrupt pose")  # fmt: skip
        return PoseVerdict(stamp, here, item, detail)


def largest_consistent(ok: npt.NDArray[np.bool_]) -> set[int]:
    """Members of any largest subset of poses that are pairwise consistent (`ok` (n, n), n <= 5):
    the poses a majority agrees on; a tie keeps both sides (nothing to tell them apart)."""
    n = ok.shape[0]
    best: list[list[int]] = []
    for size in range(n, 0, -1):
        for mask in range(1, 1 << n):
            members = [k for k in range(n) if mask >> k & 1]
            if len(members) == size and ok[np.ix_(members, members)].all():
                best.append(members)
        if best:
            break
    return {k for members in best for k in members}
