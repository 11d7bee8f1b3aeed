"""A few decoded messages of a topic: the first ones, or the first at or after given times."""

from __future__ import annotations

from collections.abc import Iterator
from itertools import islice
from typing import Any

from pipeline.ingest.sources.bags import BagFile, Message


def holders(bags: list[BagFile], topic: str) -> list[BagFile]:
    """The bags holding `topic`, in name order (split bags `_0`, `_1`: time order)."""
    return [b for b in bags if topic in b.topics()]


def first(bags: list[BagFile], topic: str, n: int) -> Iterator[tuple[Message, Any]]:
    """(raw, decoded) of the first `n` messages of `topic` (the first bag that holds it first)."""
    left = n
    for bag in holders(bags, topic):
        for msg in islice(bag.messages([topic]), left):
            left -= 1
            yield msg, bag.deserialize(msg)
        if left <= 0:
            return


def at(bags: list[BagFile], topic: str, start_ns: int) -> tuple[Message, Any] | None:
    """(raw, decoded) of the first message of `topic` with log time >= `start_ns`."""
    best: tuple[Message, BagFile] | None = None
    for bag in holders(bags, topic):
        msg = next(iter(bag.messages([topic], start=start_ns)), None)
        if msg is not None and (best is None or msg.bag_time_ns < best[0].bag_time_ns):
            best = (msg, bag)
    if best is None:
        return None
    return best[0], best[1].deserialize(best[0])
