"""A recorded pose track read at many stamps at once (pure math, no I/O).

`BatchTrack` reads what `packets.reprojection_consistency.Track.at` reads at one stamp (linear
translation, slerp rotation between the neighbouring samples), for an array of stamps in one
call: one scipy `Slerp` evaluation and one `np.interp` per axis instead of one per stamp. The
arithmetic per stamp is the same, so each pose equals `Track.at`'s bit for bit (pinned by a
test on random tracks).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation, Slerp

F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]


class BatchTrack:
    """Poses T_world_x (N, 4, 4) at stamps (N,) ns (int64, strictly increasing), read at many
    stamps at once (module docstring)."""

    def __init__(self, stamps_ns: npt.ArrayLike, T_world_x: npt.ArrayLike) -> None:
        self.t = np.asarray(stamps_ns, np.int64)
        self.T = np.asarray(T_world_x, np.float64)
        if self.t.size < 2 or bool((np.diff(self.t) <= 0).any()):
            raise ValueError("a track needs >= 2 strictly increasing stamps")
        self._rel0 = self.t[0]
        self._rel = (self.t - self._rel0) * 1e-9
        self._slerp = Slerp(self._rel, Rotation.from_matrix(self.T[:, :3, :3]))

    def at_many(self, stamps_ns: npt.ArrayLike) -> tuple[F64, Bool]:
        """Poses (M, 4, 4) at stamps (M,) ns (int or float: the same arithmetic as a scalar
        stamp of that type) and whether each lies in the recorded span (M,); a pose outside
        the span is the identity (never read: `Track.at` gives None there)."""
        s_ns = np.asarray(stamps_ns)
        if s_ns.dtype.kind not in "iuf":
            s_ns = s_ns.astype(np.float64)
        s_ns = s_ns.reshape(-1)
        inside: Bool = (s_ns >= self.t[0]) & (s_ns <= self.t[-1])
        out = np.tile(np.eye(4), (len(s_ns), 1, 1))
        if inside.any():
            s = (s_ns[inside] - self._rel0) * 1e-9
            R = self._slerp(s).as_matrix()
            pos = np.stack([np.interp(s, self._rel, self.T[:, k, 3]) for k in range(3)], 1)
            out[inside, :3, :3] = R
            out[inside, :3, 3] = pos
        return out, inside
