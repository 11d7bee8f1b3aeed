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

import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from pipeline.ingest.calib.tf_tree import TfTree
from pipeline.ingest.sources.registry import source_for
from pipeline.inspect.config_cameras import camera_keys
from pipeline.inspect.decide import lidar_keys
from pipeline.inspect.model import CloudReport, Decision, Inspection
from schemas.config import M3GDConfig, TopicsConfig, parse_config, write_config_text

if TYPE_CHECKING:
    from pipeline.inspect.prove import ProofReport


@dataclass
class Rig:
    """The keys decided so far: ingest topics, ingest cameras, hf groups, warnings."""

    topics: dict[str, Any] = field(default_factory=dict)
    cameras: list[str] = field(default_factory=list)
    hf: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def _decision(ins: Inspection, what: str) -> Decision | None:
    """The inspection's decision about `what` (pose, lidar, camera <topic>), or None."""
    return next((d for d in ins.decisions if d.what == what), None)


def _cameras(ins: Inspection, rig: Rig, hf: bool) -> None:
    """Camera keys: every usable camera under its own name (`config_cameras`), each with the
    frame inspect decided (its image's or its camera_info's, the one the TF tree holds)."""
    cams = []
    for cam in ins.cameras:
        d = _decision(ins, f"camera {cam.image_topic}")
        cams.append(replace(cam, frame_id=d.chosen) if d is not None and d.chosen else cam)
    keys = camera_keys(tuple(cams), hf)
    rig.cameras = keys.names
    rig.topics.update(keys.topics)
    rig.hf.update(keys.hf)
    rig.warnings += keys.warnings


def lidar_name(cloud: CloudReport, taken: list[str]) -> str:
    """A name for a LiDAR of `lidars:`: its frame (`/` as `_`), else its topic's segments
    joined; numbered when taken."""
    base = cloud.frame_id.strip("/").replace("/", "_") or "_".join(
        s for s in cloud.topic.split("/") if s) or "lidar"  # fmt: skip
    base = re.sub(r"[^A-Za-z0-9_.-]", "_", base).lstrip("_.") or "lidar"
    name, i = base, 2
    while name in taken:
        name, i = f"{base}_{i}", i + 1
    return name


def _lidar(ins: Inspection, rig: Rig, hf: bool) -> None:
    """LiDAR keys: the reference LiDAR inspect decided (the most messages); with several, every
    one declared under `lidars:` (the reference first, merging off, told how to turn it on);
    a topic without messages or unreadable named and left out."""
    d = _decision(ins, "lidar")
    by_topic = {c.topic: c for c in ins.clouds}
    cands = [c for c in (d.candidates if d else ()) if c.name in by_topic]
    for c in cands:
        if not c.usable:
            rig.warnings.append(f"LiDAR {c.name}: {'; '.join(c.evidence)}")
    good = [by_topic[c.name] for c in cands if c.usable]
    if not ins.clouds:
        rig.warnings.append("no PointCloud2 topic: no LiDAR configured")
        return
    if not good:
        rig.warnings.append("no PointCloud2 topic with readable messages: no LiDAR configured")
        return
    lidar = good[0]
    if hf or len(good) == 1:
        rig.topics["lidar_frame"] = lidar.frame_id
        _point_time(lidar, rig)
        if hf:
            rig.hf["lidar_group"] = lidar.topic
        else:
            rig.topics["lidar"] = lidar.topic
        for other in good[1:]:
            rig.warnings.append(f"LiDAR {other.topic}: left out (the file configures one LiDAR: "
                                f"{lidar.topic}, the one with the most messages; to index or "
                                "merge several, declare them in ingest.topics.lidars and "
                                "select.lidar)")
        return
    names: list[str] = []
    lidars: dict[str, Any] = {}
    for cloud in good:
        name = lidar_name(cloud, names)
        names.append(name)
        keys = lidar_keys(cloud)
        lidars[name] = {k: v for k, v in keys.items() if k != "point_time" or v != "auto"}
        if keys["point_time"] == "auto":
            _point_time(cloud, Rig(warnings=rig.warnings))
    rig.topics["lidars"] = lidars
    rig.warnings.append(f"LiDARs {', '.join(names)} declared, {names[0]} ({lidar.topic}, the "
                        f"most messages) the reference; the packets carry its sweeps only: to "
                        f"merge them all, set select.lidar: [{', '.join(names)}]")


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


def _odometry(ins: Inspection, rig: Rig, hf: bool) -> None:
    """Odometry keys: the pose source inspect decided (`decide.decide_pose`: an odometry topic,
    else the moving /tf edge between a world frame and the body), told in a warning when the
    evidence left it ambiguous."""
    d = _decision(ins, "pose")
    if d is None or not d.chosen:
        rig.warnings.append("no odometry: no Odometry topic and no dynamic TF edge to the body")
        return
    keys = dict(d.keys)
    if "odometry" in keys:
        topic = keys.pop("odometry")
        if hf:
            rig.hf["odometry_group"] = topic
        else:
            rig.topics["odometry"] = topic
        child = next((o[2] for o in ins.odometry if o[0] == topic), "")
        if not child and not hf and keys.get("base_frame"):
            types = {t.topic: t.msgtype for t in ins.topics}
            rig.warnings.append(
                f"odometry {topic} ({types.get(topic, '?')}) names no child frame: its "
                f"poses are taken as those of {keys['base_frame']!r}, the root of the LiDAR's "
                "static tree (ingest.topics.base_frame)")
        rig.topics.update(keys)
    else:
        rig.topics.update(keys)
        rig.warnings.append(f"no odometry topic: odometry from the {keys['odom_frame']}-"
                            f"{keys['base_frame']} edge of {keys['tf']}")
    if d.ambiguous:
        rig.warnings.append(f"AMBIGUOUS {d.line()}")


def _chains(ins: Inspection, rig: Rig) -> None:
    """Warnings for sensor frames the static tree does not connect to the base frame."""
    tree = _static_tree(ins)
    base = rig.topics.get("base_frame", "base")
    topics = TopicsConfig.model_validate(rig.topics)
    frames = [x.frame for x in topics.lidar_rig()] if "lidars" in rig.topics else [
        rig.topics.get("lidar_frame", "")]  # fmt: skip
    frames += [topics.frame_of(c) for c in rig.cameras]
    reach = set(tree.connected(base)) if base in tree.frames else {base}
    for frame in frames:
        if frame and frame not in reach:
            rig.warnings.append(f"frame {frame!r} is not connected to the base frame {base!r} "
                                "by static transforms (ingest.topics.base_frame)")


def _ambiguous_sensors(ins: Inspection, rig: Rig) -> None:
    """A warning for every LiDAR or camera decision the evidence left ambiguous."""
    for d in ins.decisions:
        if d.ambiguous and d.what != "pose":
            rig.warnings.append(f"AMBIGUOUS {d.line()}")


def decision_lines(ins: Inspection, proof: ProofReport | None = None) -> list[str]:
    """Every decision of the inspection in one line each (`Decision.line`), its geometry
    proof after it (`prove.Proof.summary`: the status, each candidate's verdict and score)
    when proven; then the proofs of what is not one of its decisions (the point-time
    convention, a layout's one rig), one line each."""
    out = []
    for d in ins.decisions:
        p = proof.of(d.what) if proof is not None else None
        out.append(d.line() + (f" | geometry: {p.summary()}" if p is not None else ""))
    if proof is not None:
        decided = {d.what for d in ins.decisions}
        out += [f"{p.what}: geometry: {p.summary()}" for p in proof.proofs
                if p.what not in decided]
    return out


def config_mapping(ins: Inspection, recording: Path) -> tuple[dict[str, Any], list[str]]:
    """The configuration keys for `recording` as a mapping, and the warnings."""
    hf = ins.format.startswith("hf-zarr")
    source = source_for(recording)
    rig = Rig()
    _cameras(ins, rig, hf)
    if not getattr(source, "fixed_rig", False):  # a layout that fixes its rig by file
        # leaves nothing to decide (a source registered before the key: it decides)
        _lidar(ins, rig, hf)
        _odometry(ins, rig, hf)
        tf_static = [t.topic for t in ins.topics if t.topic.rstrip("/").endswith("tf_static")]
        if not hf and tf_static:
            rig.topics["tf_static"] = tf_static[0]
        _chains(ins, rig)
        _ambiguous_sensors(ins, rig)
    ingest: dict[str, Any] = {"recordings": [str(recording.resolve())],
                              "format": source.name, "topics": rig.topics}
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


def write_config(cfg: M3GDConfig, path: Path, warnings: list[str],
                 decisions: list[str] | None = None) -> None:  # fmt: skip
    """Write `cfg` as YAML to `path`, the warnings and then inspect's decisions (one line
    each, `decision_lines`) as comments above it."""
    lines = [*warnings, *(f"decided {line}" for line in decisions or ())]
    head = "".join("# " + w.replace("\r", "\\r").replace("\n", "\\n") + "\n" for w in lines)
    write_config_text(path, "# written by m3gd inspect; every other key keeps its default\n"
                      + head + config_yaml(cfg))  # whole or not at all
