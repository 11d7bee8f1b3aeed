"""The TF tree of a recording: static edges (all of them) and dynamic ones (from the first
messages), as written, with roots and frames that have more than one parent.

Each `geometry_msgs/TransformStamped` is an edge header.frame_id (parent) -> child_frame_id.
A topic is static when its name ends in `tf_static` (`/tf_static` is latched and written
once per publisher). Leading slashes are dropped, as tf2 does.
"""

from __future__ import annotations

from collections.abc import Iterable

from pipeline.ingest.bags import BagFile
from pipeline.ingest.tf_tree import TfTree, transform_to_T
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


def tf_report(bags: list[BagFile], topics: dict[str, str]) -> tuple[TfReport, TfTree]:
    """The tree of every TF topic in `topics` (topic -> type), and a `TfTree` of its edges
    (the first transform of each) for chain queries."""
    counts: dict[tuple[str, str, bool, str], int] = {}
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
                if key not in counts:
                    tree.add(key[0], key[1], transform_to_T(ts.transform))
                counts[key] = counts.get(key, 0) + 1
        sampled[topic] = n
    edges = tuple(TfEdge(p, c, s, t, n) for (p, c, s, t), n in sorted(counts.items()))
    return shape(edges, sampled), tree


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
