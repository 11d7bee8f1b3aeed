"""Checks that nothing was lost silently: the accounting and the damage of an ingested recording.

`accounting_gaps` recounts, from the index tables themselves, what the accounting table says
was kept and rejected per bag file and topic. `silent_losses` compares with the messages of the
intact bags (a clean twin): every message must have been read, or lie in a reported damaged
region (its topic and log time inside the region's). Used by the tests and `m3gd bench fuzz`.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Collection, Iterable
from pathlib import Path

from pipeline.ingest.sources.bags import BagFile
from schemas.recording_index import (
    ACCOUNTING,
    DAMAGE,
    IMAGES,
    MESSAGE_REASONS,
    ODOMETRY,
    REJECTS,
    SWEEPS,
    read_index_table,
    table_path,
)

Key = tuple[str, str]  # (bag file, topic)


def accounting_gaps(idx: Path, pose_topics: Collection[str]) -> dict[Key, int]:
    """(file, topic) -> read - kept - rejected, recounted from the tables (empty when it holds).

    Images and sweeps are counted by their rows' file and topic; the odometry table has no file
    column, so its row count is checked against the kept count of `pose_topics` in total;
    rejects are counted by file, topic and a reason that drops one message.
    """
    acc = read_index_table(table_path(idx, "accounting"), ACCOUNTING).to_pylist()
    rows: Counter[Key] = Counter()
    for name, schema in (("images", IMAGES), ("sweeps", SWEEPS)):
        table = read_index_table(table_path(idx, name), schema).select(["file", "topic"])
        rows.update((r["file"], r["topic"]) for r in table.to_pylist())
    drops = {m.value for m in MESSAGE_REASONS}
    rejected: Counter[Key] = Counter(
        (r["file"], r["topic"])
        for r in read_index_table(table_path(idx, "rejects"), REJECTS).to_pylist()
        if r["reason"] in drops
    )
    gaps: dict[Key, int] = {}
    pose_kept = 0
    for a in acc:
        key = (a["file"], a["topic"])
        if a["topic"] in pose_topics:
            kept = a["kept"]
            pose_kept += kept
        else:
            kept = rows.get(key, 0)
        gap = a["read"] - kept - rejected.get(key, 0)
        if gap:
            gaps[key] = gap
    poses = read_index_table(table_path(idx, "odometry"), ODOMETRY).num_rows
    if pose_kept != poses:
        gaps[("", "odometry table rows")] = pose_kept - poses
    return gaps


def message_times(mission: Path, topics: Iterable[str]) -> dict[Key, list[int]]:
    """(file, topic) -> log times (ns) of every message of `topics` in an intact mission."""
    from pipeline.ingest.sources.bags import find_bags

    out: dict[Key, list[int]] = {}
    for path in find_bags(mission):
        bag = BagFile(path, mission)
        try:
            for msg in bag.messages(sorted(set(topics) & set(bag.topics()))):
                out.setdefault((msg.file, msg.topic), []).append(msg.bag_time_ns)
        finally:
            bag.close()
    return out


def silent_losses(clean: dict[Key, list[int]], idx: Path) -> dict[Key, int]:
    """(file, topic) -> messages of the clean twin neither read nor inside a damaged region."""
    read = {(a["file"], a["topic"]): a["read"]
            for a in read_index_table(table_path(idx, "accounting"), ACCOUNTING).to_pylist()}
    damage = read_index_table(table_path(idx, "damage"), DAMAGE).to_pylist()
    out = {}
    for (file, topic), times in clean.items():
        regions = [d for d in damage if d["file"] == file and (not d["topics"] or
                                                                 topic in d["topics"])]
        covered = sum(any(d["first_ns"] <= t <= d["last_ns"] for d in regions) for t in times)
        lost = len(times) - read.get((file, topic), 0) - covered
        if lost > 0:
            out[(file, topic)] = lost
    return out
