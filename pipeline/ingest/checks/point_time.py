"""Each LiDAR topic's point-time convention, decided once, on its first sweeps.

`ingest.topics.lidar_point_time` declares it (`{field, unit, reference}`), switches it off
(`none`: every point takes its header stamp) or leaves it to `auto`: the first
`AUTO_SWEEPS` sweeps of the topic are held, their evidence read
(`schemas.time_conventions.infer`), the decision made, and the held sweeps released under it.
The decision and its evidence become a `point_time` row of the checks table (and so of the
manifest); where no convention fits, one warning per topic says the points take their header
stamps. Nothing here rejects a message.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from pipeline.ingest.sources.pointcloud import cloud_view, sweep_times, time_field
from schemas.config_sections import PointTimeConfig
from schemas.errors import DataError
from schemas.time_conventions import (
    AUTO_SWEEPS,
    PointTimeDecision,
    SweepTimes,
    TimeConvention,
    TimeEvidence,
    configured,
    infer,
)

CHECK = "point_time"
"""The checks-table name of a topic's point-time decision."""
Setting = Literal["auto", "none"] | PointTimeConfig


@dataclass
class PointTimes:
    """Point-time decisions per topic, and the sweeps held until their topic's is made.

    Items are (message, deserialized PointCloud2, header stamp ns), as the stream has them.
    """

    setting: Setting = "auto"
    per_topic: dict[str, Setting] = field(default_factory=dict)
    decisions: dict[str, PointTimeDecision] = field(default_factory=dict)
    held: dict[str, list[tuple[Any, Any, int]]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def hold(self, topic: str, item: tuple[Any, Any, int]) -> list[tuple[Any, Any, int]] | None:
        """None when `topic` is decided (handle `item` now); else the topic's held sweeps with
        `item` added (decide once AUTO_SWEEPS are held)."""
        if topic in self.decisions:
            return None
        held = self.held.setdefault(topic, [])
        held.append(item)
        return held

    def convention(self, topic: str) -> TimeConvention | None:
        """The decided convention of `topic` (None: header stamps)."""
        d = self.decisions.get(topic)
        return d.convention if d else None

    def release(self, topic: str) -> list[tuple[Any, Any, int]]:
        """Decide `topic` on its held sweeps; those sweeps, in arrival order."""
        items = self.held.pop(topic, [])
        self.decisions[topic] = decision = self._decide(items, self.setting_of(topic))
        if decision.source == "none" and self.setting_of(topic) == "auto":
            self.notes.append(f"{topic}: no point-time convention fits ({decision.reason}; "
                              f"{decision.evidence.line()}): every point takes its sweep's "
                              "header stamp (told once per topic; declare one in "
                              "ingest.topics.lidar_point_time)")  # fmt: skip
        elif decision.source == "config" and decision.reason:
            self.notes.append(f"{topic}: lidar_point_time {decision.line()}")
        return items

    def setting_of(self, topic: str) -> Setting:
        """The configured point-time setting of `topic` (its LiDAR's own, else `setting`)."""
        return self.per_topic.get(topic, self.setting)

    def _decide(self, items: list[tuple[Any, Any, int]], setting: Setting) -> PointTimeDecision:
        """The decision on the held sweeps' evidence, as `setting` asks."""
        if setting == "none":
            return PointTimeDecision(None, "none", TimeEvidence(0),
                                     "set by ingest.topics.lidar_point_time")  # fmt: skip
        name = setting.field if isinstance(setting, PointTimeConfig) else None
        samples: list[SweepTimes] = []
        dtype = ""
        for _, obj, stamp in items:
            try:
                view = cloud_view(obj)
            except (DataError, ValueError, AttributeError):
                continue  # an undecodable cloud is rejected on release, no evidence
            name = name or time_field(view.arr)
            if name is not None and name in (view.arr.dtype.names or ()):
                dtype = dtype or view.arr.dtype.fields[name][0].base.name  # type: ignore[index]
            samples.append(sweep_times(view, stamp, name))
        if isinstance(setting, PointTimeConfig):
            s = setting
            return configured(TimeConvention(s.field, dtype, s.unit, s.reference), samples)
        return infer(name, dtype or "V", samples)

    def pending(self) -> list[str]:
        """Topics with sweeps still held (the end of the stream: decide on what there is)."""
        return sorted(self.held)

    def rows(self) -> list[dict[str, object]]:
        """Checks-table rows: one per decided topic (`on` with a convention, else `off`)."""
        return [{"topic": t, "check": CHECK, "state": "on" if d.convention else "off",
                 "messages": d.evidence.sweeps, "flagged": 0, "rejected": 0, "trusted": 0,
                 "detail": d.line()} for t, d in sorted(self.decisions.items())]  # fmt: skip


__all__ = ["AUTO_SWEEPS", "CHECK", "PointTimes", "Setting"]
