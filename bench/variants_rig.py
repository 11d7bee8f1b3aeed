"""Rig variants and inspect-written configurations for `m3gd bench variants`.

A rig variant (`pipeline.synth.variants_rig.RIG_VARIANTS`) is a written mission changed
afterwards (cameras renamed, raw or PNG images, a CameraInfo change, split bags, a rosbag2
folder, pose odometry) or a TF / pose-source variant (`pipeline.synth.variants_tf`: wheels
on /tf, odom as base's child, map -> odom jumps, a second root, an odometry topic that
disagrees with /tf, an image frame_id the tree lacks, a second LiDAR at half rate):
`rig_mission` writes the default sensors' mission of the bench's size
and applies the change. No config of the default's fits a renamed rig; every rig variant runs
under the configuration `m3gd inspect --write-config` writes for it (`inspect_config`).

`inspect_config` is what the CLI does: inspect the recording, write the YAML (warnings as
comments) and read it back as `m3gd -c <file> run` would; `decision_truth` is what its
decisions must be on each variant, `wrong_decisions` where they are not. The bench then sets
only what is not the recording's: the output folder, the output image size of every bench
run, the checks judging every message (`trust_checksums` off) and one worker (`BENCH_KEYS`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from pipeline.synth.variants_tf import TF_VARIANTS, Truth, apply_tf_variant
from schemas.config import M3GDConfig, SynthConfig, TopicsConfig, parse_config

RIG_CAMERAS: dict[str, tuple[str, ...]] = {
    "camera_names": ("alphasense_front_left", "zed2i_right", "thermal"),
}
"""Cameras of the rig variants that rename them (others: the bench's one camera, `front`);
`ten_cameras` takes `variants_rig.TEN_CAMERAS`."""
RAW_ENCODING = "bayer_grbg16"
"""The raw encoding of `raw_images` (a 16-bit Bayer mosaic: demosaic and bit depth at once)."""


def rig_cameras(name: str, default: list[str]) -> list[str]:
    """The cameras the mission of rig variant `name` is written with."""
    from pipeline.synth.variants_rig import TEN_CAMERAS

    if name == "ten_cameras":
        return list(TEN_CAMERAS)
    return list(RIG_CAMERAS.get(name, default))


def rig_mission(root: Path, name: str, synth: dict[str, Any]) -> Path:
    """Write the mission of rig variant `name` under `root/<name>/` (the default sensors,
    `synth`'s size and scene) and apply the variant's change; its folder."""
    from pipeline.synth import variants_rig as rig
    from pipeline.synth.api import synthesize

    cfg = SynthConfig.model_validate({k: v for k, v in synth.items() if k != "scenes"})
    cameras = rig_cameras(name, list(cfg.cameras))
    renamed = cameras != list(cfg.cameras)
    topics = TopicsConfig(per_camera=rig.rig_topics(cameras)) if renamed else None
    cfg = cfg.model_copy(update={"cameras": cameras, "variant": "default",
                                 "second_lidar": name == "two_lidars"})
    synthesize(root, cfg, synth.get("scenes", ["corridor"])[0], name, topics)
    mission = root / name
    if name == "raw_images":
        rig.to_raw_images(mission, RAW_ENCODING)
    elif name == "png_images":
        rig.to_raw_images(mission, "png")
    elif name == "camera_info_change":
        bag = f"hdr_{cameras[0]}"
        rig.change_camera_info(mission, bag, _mid_ns(next(mission.glob(f"*_{bag}.bag"))))
    elif name == "split_bags":
        rig.split_bags(mission)
    elif name == "rosbag2_folder":
        rig.to_rosbag2_folder(mission)
    elif name in ("pose_stamped", "pose_with_covariance"):
        rig.odometry_as(mission, rig.POSE_T if name == "pose_stamped" else rig.POSE_COV_T)
    elif name in TF_VARIANTS:
        t = topics or TopicsConfig()
        apply_tf_variant(mission, name, t.image_topic(cameras[0]), (t.lidar, t.lidar_frame))
    return mission


def decision_truth(name: str, cameras: list[str], lidar_frame: str | None = None,
                   camera_frame: str | None = None) -> Truth:  # fmt: skip
    """What inspect must decide on the recording of variant `name` (a sensor, rig or TF
    variant) with `cameras`: the default pose source (the odometry topic, odom -> base), the
    LiDAR (and `two_lidars`' second), each camera's frame (a renamed rig's own; a sensor
    variant's `lidar_frame` / `camera_frame` template); a TF variant's changes on top."""
    from pipeline.synth import variants_rig as rig
    from pipeline.synth.streams import SECOND_LIDAR

    renamed = name in RIG_CAMERAS or name == "ten_cameras"
    t = TopicsConfig(per_camera=rig.rig_topics(cameras)) if renamed else TopicsConfig(
        **({"camera_frame": camera_frame} if camera_frame else {}),
        **({"lidar_frame": lidar_frame} if lidar_frame else {}))  # fmt: skip
    raw = name == "raw_images"  # its images move to the topic without /compressed
    truth = Truth({"odometry": t.odometry, "odom_frame": t.odom_frame,
                   "base_frame": t.base_frame}, False,
                  (t.lidar, *((SECOND_LIDAR[0],) if name == "two_lidars" else ())),
                  {t.image_topic(c).removesuffix("/compressed") if raw else t.image_topic(c):
                   t.frame_of(c) for c in cameras})  # fmt: skip
    return TF_VARIANTS[name].truth(truth) if name in TF_VARIANTS else truth


def wrong_decisions(decisions: Any, truth: Truth) -> list[str]:
    """Where inspect's `decisions` differ from `truth`, one line each (`decide.mismatches`)."""
    from pipeline.inspect.decide import mismatches

    return mismatches(decisions, truth.pose, truth.pose_ambiguous, truth.lidars,
                      truth.camera_frames)  # fmt: skip


def _mid_ns(bag: Path) -> int:
    """The middle (ns) of a ROS1 bag's log-time span (the generator logs at the header stamp)."""
    from rosbags.rosbag1 import Reader

    with Reader(bag) as reader:
        return int((reader.start_time + reader.end_time) // 2)


def inspect_config(mission: Path, path: Path) -> tuple[dict[str, Any], list[str], Any]:
    """What `m3gd inspect <mission> --write-config <path>` writes (its decisions proven by their
    geometry, as by default), read back from `path` (a mapping), with its warnings and the
    inspection (its decisions, its time)."""
    from pipeline.inspect.config_out import build_config, decision_lines, write_config
    from pipeline.inspect.prove import prove_or_say
    from pipeline.inspect.recording import inspect_recording

    report, ins = prove_or_say(inspect_recording(mission), mission)
    cfg, warnings = build_config(ins, mission)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_config(cfg, path, warnings, decision_lines(ins, report))
    raw: dict[str, Any] = yaml.safe_load(path.read_text())
    return raw, warnings, ins


def merged_lidars(raw: dict[str, Any]) -> dict[str, Any]:
    """`raw` (an inspect-written configuration, which declares every LiDAR under
    `ingest.topics.lidars`, merging off) with merging turned on as its comment says:
    `select.lidar` lists them all, the reference first."""
    names = list(raw.get("ingest", {}).get("topics", {}).get("lidars", {}))
    if len(names) < 2:
        return raw
    return {**raw, "select": {**raw.get("select", {}), "lidar": names}}


def bench_keys(raw: dict[str, Any], out: Path, ingest: dict[str, Any]) -> M3GDConfig:
    """`raw` (a written configuration) with the bench's own keys: the output folder, `ingest`'s
    output size and checks, one worker and no retries."""
    keys = {k: ingest[k] for k in ("out_height", "out_width", "checks") if k in ingest}
    return parse_config({**raw, "output_dir": str(out),
                         "ingest": {**raw.get("ingest", {}), **keys},
                         "cache": {"shard_views": 8}, "dag": {"retries": 0, "workers": 1}})
