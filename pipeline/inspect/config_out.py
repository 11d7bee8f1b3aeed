"""A configuration `m3gd run` accepts, made from an inspection.

`config_mapping` decides the keys (one function per section of the rig: cameras, LiDAR,
odometry, frames); `build_config` validates them through the pydantic model
(`schemas.config.M3GDConfig`), so what `write_config` writes is valid by construction. Only
the keys inspect decides are written; every other key keeps its default. Each decision that
leaves something out (a camera the config cannot name, a second LiDAR) is returned as a
warning line.

Cameras: every camera with a calibration and a frame, under its own name, with a template or
its own topics and frame (`pipeline.inspect.config_cameras`).

LiDAR point time: the convention inspect decided from the first sweeps' evidence (ingest's
own inference, `schemas.time_conventions`) is written out as `ingest.topics.lidar_point_time:
{field, unit, reference}`, so a run reads the declared convention instead of guessing again;
`auto` (with a warning comment) when the evidence decided none.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pipeline.ingest.tf_tree import TfTree
from pipeline.inspect.config_cameras import camera_keys
from pipeline.inspect.model import CloudReport, Inspection
from schemas.config import M3GDConfig, TopicsConfig, parse_config


@dataclass
class Rig:
    """The keys decided so far: ingest topics, ingest cameras, hf groups, warnings."""

    topics: dict[str, Any] = field(default_factory=dict)
    cameras: list[str] = field(default_factory=list)
    hf: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def _cameras(ins: Inspection, rig: Rig, hf: bool) -> None:
    """Camera keys: every usable camera under its own name (`config_cameras`)."""
    keys = camera_keys(ins.cameras, hf)
    rig.cameras = keys.names
    rig.topics.update(keys.topics)
    rig.hf.update(keys.hf)
    rig.warnings += keys.warnings


def _lidar(ins: Inspection, rig: Rig, hf: bool) -> None:
    """LiDAR keys: the PointCloud2 topic (or HF group) with the most messages."""
    counts = {t.topic: t.count for t in ins.topics}
    clouds = sorted(ins.clouds, key=lambda c: (-counts.get(c.topic, 0), c.topic))
    if not clouds:
        rig.warnings.append("no PointCloud2 topic: no LiDAR configured")
        return
    lidar = clouds[0]
    rig.topics["lidar_frame"] = lidar.frame_id
    _point_time(lidar, rig)
    if hf:
        rig.hf["lidar_group"] = lidar.topic
    else:
        rig.topics["lidar"] = lidar.topic
    for other in clouds[1:]:
        rig.warnings.append(f"LiDAR {other.topic}: left out (the file configures one LiDAR: "
                            f"{lidar.topic}, the one with the most messages; to index or "
                            "merge several, declare them in ingest.topics.lidars and "
                            "select.lidar)")


def _point_time(cloud: CloudReport, rig: Rig) -> None:
    """`lidar_point_time`: the convention inspect's evidence decided (`clouds.decide_convention`,
    ingest's inference), declared so that ingest reads it rather than inferring it again;
    `auto` with a warning when the evidence decided none."""
    conv = cloud.convention
    if cloud.time_field and conv.unit is not None and conv.reference is not None:
        rig.topics["lidar_point_time"] = {"field": cloud.time_field, "unit": conv.unit,
                                          "reference": conv.reference}  # fmt: skip
        return
    rig.topics["lidar_point_time"] = "auto"
    why = (f"field {cloud.time_field!r}: {conv.note or conv.decided_by}" if cloud.time_field
           else "no per-point time field")  # fmt: skip
    rig.warnings.append(f"LiDAR {cloud.topic}: point-time convention undecided ({why}); "
                        "ingest.topics.lidar_point_time stays auto (ingest infers it per "
                        "recording; declare {field, unit, reference} if known)")


def _static_tree(ins: Inspection) -> TfTree:
    """The static edges as a TfTree (identity transforms: connectivity only)."""
    tree = TfTree()
    for e in ins.tf.edges:
        if e.static:
            tree.add(e.parent, e.child, np.eye(4))
    return tree


def _body_root(ins: Inspection, static: TfTree, lidar_frame: str) -> str:
    """The root of the static tree holding the LiDAR frame (else the only root), or ''."""
    children = {e.child for e in ins.tf.edges if e.static}
    if lidar_frame in static.frames:
        roots = [f for f in static.connected(lidar_frame) if f not in children]
        if len(roots) == 1:
            return roots[0]
    return ins.tf.roots[0] if len(ins.tf.roots) == 1 else ""


def _odometry(ins: Inspection, rig: Rig, hf: bool) -> None:
    """Odometry keys: the first odometry topic (nav_msgs/Odometry first, then the pose types)
    and its frames, else a dynamic TF edge to the body."""
    lidar_frame = rig.topics.get("lidar_frame", "")
    static = _static_tree(ins)
    if ins.odometry:
        topic, odom, base = ins.odometry[0]
        if hf:
            rig.hf["odometry_group"] = topic
        else:
            rig.topics["odometry"] = topic
        rig.topics["odom_frame"] = odom or "odom"
        if not base:  # a pose message names no child frame: the body's static root
            base = _body_root(ins, static, lidar_frame)
            types = {t.topic: t.msgtype for t in ins.topics}
            if not hf and base:
                rig.warnings.append(
                    f"odometry {topic} ({types.get(topic, '?')}) names no child frame: its "
                    f"poses are taken as those of {base!r}, the root of the LiDAR's static "
                    "tree (ingest.topics.base_frame)")
        if base:
            rig.topics["base_frame"] = base
        return
    body = set(static.connected(lidar_frame)) if lidar_frame in static.frames else set()
    for e in ins.tf.edges:
        if not e.static and (e.parent in body) != (e.child in body):
            base, odom = (e.parent, e.child) if e.parent in body else (e.child, e.parent)
            rig.topics.update({"tf": e.topic, "base_frame": base, "odom_frame": odom})
            rig.warnings.append(f"no odometry topic: odometry from the {odom}-{base} "
                                f"edge of {e.topic}")
            return
    rig.warnings.append("no odometry: no Odometry topic and no dynamic TF edge to the body")


def _chains(ins: Inspection, rig: Rig) -> None:
    """Warnings for sensor frames the static tree does not connect to the base frame."""
    tree = _static_tree(ins)
    base = rig.topics.get("base_frame", "base")
    topics = TopicsConfig.model_validate(rig.topics)
    frames = [rig.topics.get("lidar_frame", "")] + [topics.frame_of(c) for c in rig.cameras]
    reach = set(tree.connected(base)) if base in tree.frames else {base}
    for frame in frames:
        if frame and frame not in reach:
            rig.warnings.append(f"frame {frame!r} is not connected to the base frame {base!r} "
                                "by static transforms (ingest.topics.base_frame)")


def config_mapping(ins: Inspection, recording: Path) -> tuple[dict[str, Any], list[str]]:
    """The configuration keys for `recording` as a mapping, and the warnings."""
    hf = ins.format.startswith("hf-zarr")
    rig = Rig()
    _cameras(ins, rig, hf)
    _lidar(ins, rig, hf)
    _odometry(ins, rig, hf)
    tf_static = [t.topic for t in ins.topics if t.topic.rstrip("/").endswith("tf_static")]
    if not hf and tf_static:
        rig.topics["tf_static"] = tf_static[0]
    _chains(ins, rig)
    ingest: dict[str, Any] = {"recordings": [str(recording.resolve())],
                              "format": "hf-zarr" if hf else "rosbag", "topics": rig.topics}
    if rig.cameras:
        ingest["cameras"] = rig.cameras
    if hf:
        tf_groups = [e.topic.removeprefix("data/") for e in ins.tf.edges[:1]]
        ingest["hf"] = {**rig.hf, **({"tf_group": tf_groups[0]} if tf_groups else {})}
    return {"ingest": ingest}, rig.warnings


def build_config(ins: Inspection, recording: Path) -> tuple[M3GDConfig, list[str]]:
    """The validated configuration of `recording` and the warnings (ConfigError if the keys
    decided do not validate)."""
    raw, warnings = config_mapping(ins, recording)
    return parse_config(raw), warnings


def config_yaml(cfg: M3GDConfig) -> str:
    """The keys set in `cfg` (not the defaults) as YAML."""
    text: str = yaml.safe_dump(cfg.model_dump(mode="json", exclude_unset=True), sort_keys=False)
    return text


def write_config(cfg: M3GDConfig, path: Path, warnings: list[str]) -> None:
    """Write `cfg` as YAML to `path`, the warnings as comments above it."""
    head = "".join(f"# {w}\n" for w in warnings)
    path.write_text("# written by m3gd inspect; every other key keeps its default\n" + head
                    + config_yaml(cfg))
