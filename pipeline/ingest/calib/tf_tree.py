"""A static TF tree from `/tf_static` messages: edges in either direction, chains composed.

Each `geometry_msgs/TransformStamped` gives `T_parent_child` (maps child into parent). The tree
is stored undirected: walking an edge against its direction uses the inverse, so frames
published 'upside down' (e.g. `odom` as a child of `base`) resolve the same.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from typing import Any

import numpy as np

from packets.poses import F64, compose, invert_T, make_T, quat_to_rot
from pipeline.ingest.errors import MissingTransformError


def transform_to_T(tf: Any) -> F64:
    """(4, 4) float64 T_parent_child from a geometry_msgs/Transform (translation, rotation)."""
    t, q = tf.translation, tf.rotation
    return make_T(quat_to_rot([q.x, q.y, q.z, q.w]), [t.x, t.y, t.z])


class TfTree:
    """Static transforms between named frames."""

    def __init__(self) -> None:
        """An empty tree."""
        self._edges: dict[str, dict[str, F64]] = {}

    def add(self, parent: str, child: str, T_parent_child: F64) -> None:
        """Add (or replace) the edge parent -> child and its inverse."""
        parent, child = parent.lstrip("/"), child.lstrip("/")
        self._edges.setdefault(parent, {})[child] = np.asarray(T_parent_child, dtype=np.float64)
        self._edges.setdefault(child, {})[parent] = invert_T(T_parent_child)

    def add_message(self, msg: Any) -> int:
        """Add every transform of a tf2_msgs/TFMessage; returns how many."""
        for ts in msg.transforms:
            self.add(ts.header.frame_id, ts.child_frame_id, transform_to_T(ts.transform))
        return len(msg.transforms)

    @property
    def frames(self) -> list[str]:
        """All frame names, sorted."""
        return sorted(self._edges)

    def connected(self, frame: str) -> list[str]:
        """Frames reachable from `frame` (itself included), sorted."""
        return sorted(self._walk(frame.lstrip("/")))

    def _walk(self, start: str) -> dict[str, str | None]:
        """Breadth-first predecessor map from `start` over the undirected edges."""
        prev: dict[str, str | None] = {start: None}
        todo = deque([start])
        while todo:
            node = todo.popleft()
            for nxt in self._edges.get(node, {}):
                if nxt not in prev:
                    prev[nxt] = node
                    todo.append(nxt)
        return prev

    def lookup(self, target: str, source: str) -> F64:
        """(4, 4) T_target_source composed along the chain; MissingTransformError naming it."""
        target, source = target.lstrip("/"), source.lstrip("/")
        prev = self._walk(target)
        if source not in prev:
            raise MissingTransformError(self._explain(target, source, prev))
        chain: list[F64] = []
        node = source
        while (parent := prev[node]) is not None:
            chain.append(self._edges[parent][node])  # T_parent_node
            node = parent
        return compose(*reversed(chain)) if chain else np.eye(4)

    def _explain(self, target: str, source: str, reach: Iterable[str]) -> str:
        """Message naming the missing chain and the two disconnected parts."""
        near = sorted(reach)
        far = self.connected(source) if source in self._edges else []
        return (
            f"no TF chain from '{target}' to '{source}' in /tf_static: '{target}' reaches "
            f"{near}; '{source}' "
            + (f"reaches {far}" if far else "appears in no transform")
            + f"; edges known: {self.describe()}"
        )

    def describe(self) -> str:
        """All edges as 'a-b' pairs (each once), for error messages."""
        pairs = sorted({tuple(sorted((a, b))) for a, kids in self._edges.items() for b in kids})
        return ", ".join(f"{a}-{b}" for a, b in pairs) or "(none)"
