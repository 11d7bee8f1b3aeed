"""The TF tree of a recording: static edges (all of them) and dynamic ones (from the first
messages), as written, with roots and frames that have more than one parent.

Each `geometry_msgs/TransformStamped` is an edge header.frame_id (parent) -> child_frame_id.
A topic is static when its name ends in `tf_static` (`/tf_static` is latched and written
once per publisher). Leading slashes are dropped, as tf2 does.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from pipeline.ingest.calib.tf_tree import TfTree, transform_to_T
from pipeline.ingest.sources.bags import BagFile, stamp_ns
from pipeline.inspect import sample
from pipeline.inspect.model import TfEdge, TfReport

TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
DYNAMIC_SAMPLE = 200
"""Messages read per dynamic TF topic (edges published more rarely than that may be missed:
the report says how many were read)."""
STATIC_SAMPLE = 10_000
"""Messages read per static TF topic (all of them in practice)."""


def is_static(topic: str) -> bool:
    """Whether a TF topic carries static transforms."""
    return topic.rstrip("/").endswith("tf_static")


Key = tuple[str, str, bool, str]
"""(parent, child, static, topic) of an edge."""


@dataclass
class Series:
    """One dynamic edge's sampled transforms: header stamps (ns) and T_parent_child (4, 4)."""

    stamps: list[int] = field(default_factory=list)
    T: list[npt.NDArray[np.float64]] = field(default_factory=list)


def motion(series: Series) -> tuple[float | None, float, float]:
    """(rate Hz from the header stamps or None, translation path length m, longest step m) of
    an edge's sampled transforms (pure)."""
    if len(series.stamps) < 2:
        return None, 0.0, 0.0
    order = np.argsort(np.asarray(series.stamps, np.int64), kind="stable")
    t = np.asarray(series.stamps, np.int64)[order]
    xyz = np.stack([series.T[i][:3, 3] for i in order])
    steps = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    span = float(t[-1] - t[0]) / 1e9
    rate = (len(t) - 1) / span if span > 0 else None
    return rate, float(steps.sum()), float(steps.max())


def tf_report(bags: list[BagFile], topics: dict[str, str]) -> tuple[TfReport, TfTree]:
    """The tree of every TF topic in `topics` (topic -> type), and a `TfTree` of its edges
    (the first transform of each) for chain queries."""
    report, tree, _ = tf_sample(bags, topics)
    return report, tree


def tf_sample(bags: list[BagFile], topics: dict[str, str]
              ) -> tuple[TfReport, TfTree, dict[Key, Series]]:  # fmt: skip
    """`tf_report` and every dynamic edge's sampled transforms (by edge key)."""
    counts: dict[Key, int] = {}
    series: dict[Key, Series] = {}
    sampled: dict[str, int] = {}
    tree = TfTree()
    for topic in sorted(t for t, m in topics.items() if m in TF_TYPES):
        static = is_static(topic)
        n = 0
        for _, msg in sample.first(bags, topic, STATIC_SAMPLE if static else DYNAMIC_SAMPLE):
            n += 1
            for ts in msg.transforms:
                key = (ts.header.frame_id.lstrip("/"), ts.child_frame_id.lstrip("/"), static,
                       topic)  # fmt: skip
                T = transform_to_T(ts.transform)
                if key not in counts:
                    tree.add(key[0], key[1], T)
                counts[key] = counts.get(key, 0) + 1
                if not static:
                    got = series.setdefault(key, Series())
                    got.stamps.append(stamp_ns(ts))
                    got.T.append(T)
        sampled[topic] = n
    edges = tuple(TfEdge(p, c, s, t, n, *motion(series.get((p, c, s, t), Series())))
                  for (p, c, s, t), n in sorted(counts.items()))  # fmt: skip
    return shape(edges, sampled), tree, series


def shape(edges: Iterable[TfEdge], sampled: dict[str, int] | None = None) -> TfReport:
    """Roots, frames and multiple parents of a set of edges (pure)."""
    edges = tuple(edges)
    parents: dict[str, set[str]] = {}
    frames: set[str] = set()
    for e in edges:
        frames.update((e.parent, e.child))
        parents.setdefault(e.child, set()).add(e.parent)
    roots = tuple(sorted(f for f in frames if f not in parents))
    multi = {c: sorted(p) for c, p in sorted(parents.items()) if len(p) > 1}
    return TfReport(edges, roots, tuple(sorted(frames)), multi, dict(sampled or {}))


def tree_lines(report: TfReport) -> list[str]:
    """The tree as indented lines from each root: `parent -> child  (static|dynamic, topic)`.
    A frame with more than one parent is printed under each; edges no root reaches (a
    cycle) are printed from their own parent, a repeated frame marked `(cycle)`."""
    kids: dict[str, list[TfEdge]] = {}
    for e in report.edges:
        kids.setdefault(e.parent, []).append(e)
    lines: list[str] = []
    done: set[TfEdge] = set()

    def walk(frame: str, depth: int, seen: frozenset[str]) -> None:
        for e in sorted(kids.get(frame, []), key=lambda e: (e.child, e.topic)):
            done.add(e)
            kind = "static" if e.static else "dynamic"
            loop = " (cycle)" if e.child in seen else ""
            lines.append(f"{'  ' * depth}{e.parent} -> {e.child}  ({kind}, {e.topic}){loop}")
            if not loop:
                walk(e.child, depth + 1, seen | {e.child})

    for root in report.roots:
        walk(root, 0, frozenset({root}))
    for e in report.edges:
        if e not in done:
            walk(e.parent, 0, frozenset({e.parent}))
    return lines
