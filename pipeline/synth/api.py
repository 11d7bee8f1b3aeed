"""Synthesize a GrandTour-format mission: bags in `out_dir/<mission>/`, ground truth beside them.

With `format: hf-zarr` the mission is written in the Hugging Face layout instead (`data/` Zarr
store, `images/` JPEGs; see `hf_convert`), with the same ground truth.

See FORMAT.md for the output layout. Deterministic in (cfg, scene): the same inputs give the same
bags byte for byte.
"""

from __future__ import annotations

import shutil
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.synth import groundtruth as gt
from pipeline.synth.faults import FaultPlan, plan_faults, truncate_file
from pipeline.synth.hf_convert import bags_to_hf
from pipeline.synth.rig import build_rig, with_second_lidar
from pipeline.synth.rosio import Bag, Msgs, convert_to_mcap, ros1_typestore
from pipeline.synth.scene import Raycaster, build_scene
from pipeline.synth.streams import (
    SECOND_LIDAR,
    World,
    write_camera,
    write_lidar,
    write_odometry,
    write_second_lidar,
    write_tf,
)
from pipeline.synth.timeline import NS, make_timeline
from pipeline.synth.trajectory import BASE_HEIGHT_M, GAIT_HZ, Trajectory, motion_json, motion_of
from pipeline.synth.variants import VARIANTS, variant_help
from schemas.config import SynthConfig, TopicsConfig, config_to_dict
from schemas.errors import DataError
from schemas.missions import synth_mission_name
from schemas.names import check_name

HF_STAGING = ".bags"
"""Where an hf-zarr mission's bags are written before conversion (removed afterwards)."""
BAG_SUFFIXES = ("hdr_front", "hdr_left", "hdr_right", "hesai_undist", "tf_minimal", "anymal_state")


@dataclass(frozen=True)
class SynthResult:
    """What was written: mission folder, bag paths by suffix, ground-truth folder, counts."""

    mission: str
    mission_dir: Path
    bags: dict[str, Path]
    groundtruth_dir: Path
    images: dict[str, int]
    sweeps: int
    odometry: int
    faults: list[dict[str, object]] = field(default_factory=list)
    seconds_elapsed: float = 0.0
    ros2_dir: Path | None = None


def default_mission(scene: str, seed: int) -> str:
    """Mission name used when none is given: `synth_<scene>_s<seed>`, the name `m3gd run`
    gives a synthesized mission (schemas.missions.synth_mission_name)."""
    return synth_mission_name(scene, seed)


def _rng(cfg: SynthConfig, scene: str, stream: int) -> np.random.Generator:
    """Independent seeded generator per (seed, scene, stream)."""
    return np.random.default_rng(
        np.random.SeedSequence([cfg.seed, zlib.crc32(scene.encode()), stream])
    )


def apply_variant(cfg: SynthConfig, topics: TopicsConfig) -> tuple[SynthConfig, TopicsConfig]:
    """The config and frame names of `cfg.variant` (its odometry rate, its frame names);
    DataError in one line for an unknown variant or one the output format cannot carry."""
    if cfg.variant not in VARIANTS:
        raise DataError(f"unknown synth.variant {cfg.variant!r}; known: {variant_help()}")
    v = VARIANTS[cfg.variant]
    if cfg.variant != "default" and cfg.format != "rosbag":
        raise DataError(f"synth.variant {cfg.variant!r} is written as ROS1 bags only, not "
                        f"synth.format {cfg.format!r} (the Hugging Face layout has one LiDAR "
                        "layout and camera model)")  # fmt: skip
    if v.odom_hz is not None:
        cfg = cfg.model_copy(update={"odom_hz": v.odom_hz})
    frames = {k: f for k, f in (("lidar_frame", v.lidar_frame), ("camera_frame", v.camera_frame))
              if f is not None}  # fmt: skip
    return cfg, topics.model_copy(update=frames) if frames else topics


def _prepare(mission_dir: Path) -> None:
    """Create the mission folder; replace a previous synthetic one, refuse anything else."""
    if mission_dir.exists() and any(mission_dir.iterdir()):
        if not (mission_dir / gt.GT_DIR).is_dir():
            raise FileExistsError(
                f"{mission_dir} exists and is not a synthetic mission; not overwriting"
            )
        shutil.rmtree(mission_dir)
    (mission_dir / gt.GT_DIR).mkdir(parents=True)


def synthesize(
    out_dir: Path,
    cfg: SynthConfig,
    scene: str,
    mission: str | None = None,
    topics: TopicsConfig | None = None,
    camera_offset_m: tuple[float, float, float] | None = None,
) -> SynthResult:
    """Write one synthetic mission of `scene` to `out_dir/<mission>/` and return what was made.

    `camera_offset_m`: every camera rendered displaced by (x, y, z) m along its optical axes
    while /tf_static declares the calibrated pose (`streams.camera_displacement`): a
    mis-calibrated rig as it records, for the geometry check's rendered faults; recorded in
    scene.json (`camera_extrinsic_offset_m`). None: the config's
    `synth.camera_extrinsic_offset_m` (default (0, 0, 0))."""
    began = time.perf_counter()
    mission = check_name(mission or default_mission(scene, cfg.seed), "mission name")
    cfg, topics = apply_variant(cfg, topics or TopicsConfig())
    d = Path(out_dir) / mission
    _prepare(d)
    cams: list[str] = list(dict.fromkeys(cfg.cameras))
    tl = make_timeline(cfg, cams, _rng(cfg, scene, 0))
    motion = motion_of(cfg)
    seconds = (tl.end_ns - int(tl.odom_ns[0])) / NS + 2.0
    length = motion.max_speed_factor() * cfg.speed_mps * seconds
    scn = build_scene(scene, cfg.seed, length)
    rig = build_rig(
        cfg.image_width,
        cfg.image_height,
        _rng(cfg, scene, 1),
        topics.frame_of,
        topics.lidar_frame,
        topics.base_frame,
        VARIANTS[cfg.variant].camera_model,
        cams,
    )
    if cfg.second_lidar:
        rig = with_second_lidar(rig, SECOND_LIDAR[1])
    plan = plan_faults(list(cfg.faults), tl, cams)
    w = World(
        Raycaster(scn),
        Trajectory(scn.path, cfg.speed_mps, float(_rng(cfg, scene, 3).uniform(0, 2 * np.pi)),
                   motion),
        rig,
        tl,
        plan,
        cfg,
        topics,
        Msgs(ros1_typestore()),
        _rng(cfg, scene, 2),
        camera_offset_m=cfg.camera_extrinsic_offset_m if camera_offset_m is None
        else camera_offset_m,
    )
    hf = cfg.format == "hf-zarr"
    bag_dir = d / HF_STAGING if hf else d  # hf-zarr: bags are converted, then removed
    bag_dir.mkdir(exist_ok=True)
    bags = {s: bag_dir / f"{mission}_{s}.bag" for s in BAG_SUFFIXES if not s.startswith("hdr_")}
    bags.update({f"hdr_{c}": bag_dir / f"{mission}_hdr_{c}.bag" for c in cams})
    if cfg.second_lidar:
        bags["livox"] = bag_dir / f"{mission}_livox.bag"
    image_rows, sweep_rows = _write_bags(w, bags, cams, d / gt.GT_DIR, _rng(cfg, scene, 7))
    ros2_dir = None
    if cfg.ros2:
        convert_to_mcap(list(bags.values()), d / "ros2")
        ros2_dir = d / "ros2"
    if hf:
        bags_to_hf(list(bags.values()), d, topics, cams, zarr_format=cfg.hf_zarr_version)
        shutil.rmtree(bag_dir)
        bags = {}
    _truncate(plan, bags)
    _write_groundtruth(w, d / gt.GT_DIR, scn.to_json(), image_rows, sweep_rows)
    return SynthResult(
        mission,
        d,
        bags,
        d / gt.GT_DIR,
        images={c: sum(1 for r in image_rows if r["camera"] == c) for c in cams},
        sweeps=len(sweep_rows),
        odometry=int(tl.odom_ns.size),
        faults=list(plan.log),
        seconds_elapsed=time.perf_counter() - began,
        ros2_dir=ros2_dir,
    )


def _write_bags(
    w: World, bags: dict[str, Path], cams: list[str], gt_dir: Path,
    second_rng: np.random.Generator,
) -> tuple[list[dict[str, object]], list[dict[str, object]]]:
    """All bags, one after the other (the second LiDAR's last, from `second_rng`); returns
    (image rows, sweep rows of the first LiDAR)."""
    depth = None
    if w.cfg.depth_maps:
        counts = {
            c: sum(not w.plan.in_camera_gap(c, s) for s in w.tl.camera_ns[c].tolist()) for c in cams
        }
        depth = gt.DepthWriter(gt_dir / "depth", counts, w.cfg.image_height, w.cfg.image_width)
    ts = w.msgs.ts
    image_rows: list[dict[str, object]] = []
    for cam in cams:
        with Bag(bags[f"hdr_{cam}"], ts) as bag:
            image_rows += write_camera(w, bag, cam, depth)
    with Bag(bags["hesai_undist"], ts) as bag:
        sweep_rows = write_lidar(w, bag)
    with Bag(bags["tf_minimal"], ts) as bag:
        write_tf(w, bag)
    with Bag(bags["anymal_state"], ts) as bag:
        write_odometry(w, bag)
    if "livox" in bags:
        with Bag(bags["livox"], ts) as bag:
            write_second_lidar(w, bag, second_rng)
    return image_rows, sweep_rows


def _truncate(plan: FaultPlan, bags: dict[str, Path]) -> None:
    """Apply the truncated-bag fault after all bags are closed."""
    if plan.truncate is None or plan.truncate not in bags:  # hf-zarr: no bag to cut
        return
    path = bags[plan.truncate]
    before, after = truncate_file(path)
    plan.record("truncated_bag", path.name, "*", bytes_before=before, bytes_after=after)


def _write_groundtruth(
    w: World,
    gt_dir: Path,
    scene: dict[str, object],
    image_rows: list[dict[str, object]],
    sweep_rows: list[dict[str, object]],
) -> None:
    """poses, images, sweeps tables and the JSON files."""
    stamps = np.unique(np.concatenate([w.tl.odom_ns, np.asarray(w.extra_pose_ns, np.int64)]))
    gt.write_poses(gt_dir / "poses.parquet", stamps, w.traj.poses((stamps - w.tl.t0_ns) / NS))
    gt.write_rows(gt_dir / "images.parquet", image_rows, gt.IMAGES_SCHEMA)
    gt.write_rows(gt_dir / "sweeps.parquet", sweep_rows, gt.SWEEPS_SCHEMA)
    gt.write_json(gt_dir / "calibration.json", gt.calibration_json(w.rig))
    gt.write_json(gt_dir / "scene.json", _scene_json(w, scene))
    gt.write_json(gt_dir / "config.json", config_to_dict(w.cfg))
    gt.write_json(
        gt_dir / "faults.json", {"format_version": gt.FORMAT_VERSION, "faults": w.plan.log}
    )


def _scene_json(w: World, scene: dict[str, object]) -> dict[str, object]:
    """scene.json: the scene description plus trajectory parameters and camera clock offsets."""
    return {
        "format_version": gt.FORMAT_VERSION,
        **scene,
        "trajectory": {
            "speed_mps": w.traj.speed_mps,
            "gait_phase": w.traj.phase,
            "gait_hz": GAIT_HZ,
            "base_height_m": BASE_HEIGHT_M,
            "t0_ns": w.tl.t0_ns,
            **motion_json(w.traj.motion),
        },
        "camera_offset_ns": w.tl.camera_offset_ns,
        "camera_clock_offset_ns": w.tl.clock_offset_ns,
        **({"camera_extrinsic_error_deg": list(w.cfg.camera_extrinsic_error_deg)}
           if any(w.cfg.camera_extrinsic_error_deg) else {}),
        **({"camera_extrinsic_offset_m": list(w.camera_offset_m)}
           if any(w.camera_offset_m) else {}),
    }


def synthesize_all(
    out_dir: Path, cfg: SynthConfig, topics: TopicsConfig | None = None
) -> list[SynthResult]:
    """One mission per scene in `cfg.scenes` (the `make demo` default dataset)."""
    return [synthesize(out_dir, cfg, scene, topics=topics) for scene in cfg.scenes]
