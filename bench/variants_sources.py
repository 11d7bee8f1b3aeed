"""Source variants of `m3gd bench variants` (issue 48 item 2): the default recording exported
to the newer recording sources and read through them.

- `mcap_ros1`: every bag as one loose `.mcap` file in profile `ros1` (`ros1msg` schemas), as
  `mcap convert` writes it (`pipeline.synth.mcap_write.bags_to_mcap`);
- `mcap_ros2`: every bag converted to ROS 2 (`rosio.convert_to_mcap`, rosbags' converter) and
  its `.mcap` storage file taken out of the rosbag2 folder: loose files in profile `ros2`
  (`cdr` messages), as Foxglove exports them;
- `kitti360`: the KITTI-360 raw layout (`pipeline.synth.kitti360_write.bags_to_kitti360`:
  rectified PNGs, `.bin` sweeps without point time, poses at `image_00`'s frames).

Each mission keeps the generator's `groundtruth/` beside the exported files, so the bench's
accuracy figures read it as they do for a bag mission; the bags themselves are written to a
sibling folder and are not part of the mission. Like a rig variant, each runs under the
configuration `m3gd inspect --write-config` writes for it (`bench.variants_rig.inspect_config`).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

SOURCE_VARIANTS = ("mcap_ros1", "mcap_ros2", "kitti360")
"""The source variants by name (group `sources`)."""
KITTI_SEQ = "2013_05_28_drive_0000_sync"
"""The sequence name of the KITTI-360 copy."""


def source_mission(root: Path, name: str, synth: dict[str, Any]) -> Path:
    """Write the default recording of `synth`'s size and scene as bags under `root/<name>.bags/`
    and export it as source variant `name` to `root/<name>/` (with its `groundtruth/`); that
    folder."""
    from pipeline.synth.api import synthesize
    from pipeline.synth.groundtruth import GT_DIR
    from schemas.config import SynthConfig

    cfg = SynthConfig.model_validate({k: v for k, v in synth.items() if k != "scenes"})
    made = synthesize(root / f"{name}.bags", cfg, synth.get("scenes", ["corridor"])[0], name)
    bags = sorted(made.mission_dir.glob("*.bag"))
    mission = root / name
    shutil.rmtree(mission, ignore_errors=True)
    export(name, bags, mission, list(cfg.cameras))
    if name == "kitti360":
        kitti_groundtruth(made.groundtruth_dir, mission / GT_DIR, list(cfg.cameras)[:2])
    else:
        shutil.copytree(made.groundtruth_dir, mission / GT_DIR)
    return mission


def export(name: str, bags: list[Path], mission: Path, cameras: list[str]) -> None:
    """ROS1 `bags` written to `mission` as source variant `name` (module docstring)."""
    from pipeline.synth.kitti360_write import bags_to_kitti360
    from pipeline.synth.mcap_write import bags_to_mcap
    from pipeline.synth.rosio import convert_to_mcap
    from schemas.config import TopicsConfig

    if name == "mcap_ros1":
        bags_to_mcap(bags, mission)
    elif name == "mcap_ros2":
        staging = mission.parent / f"{name}.rosbag2"
        shutil.rmtree(staging, ignore_errors=True)
        mission.mkdir(parents=True)
        for folder in convert_to_mcap(bags, staging):
            (storage,) = folder.glob("*.mcap")
            shutil.copy(storage, mission / f"{folder.name}.mcap")
        shutil.rmtree(staging)
    elif name == "kitti360":
        bags_to_kitti360(bags, mission, TopicsConfig(), cameras[:2], KITTI_SEQ)
    else:
        raise KeyError(f"unknown source variant {name!r}; known: {', '.join(SOURCE_VARIANTS)}")


def kitti_groundtruth(src: Path, dst: Path, cameras: list[str]) -> None:
    """The generator's ground truth `src` for the KITTI-360 copy at `dst`: each camera named
    as its folder (`image_00`, `image_01`) and its depth maps undistorted as the copy's images
    are (`kitti360_write`'s OpenCV fisheye maps at balance 0, nearest neighbour: a depth is
    never blended across an edge; depth along the optical axis is unchanged, R_rect = I)."""
    import cv2
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq
    import zarr

    from pipeline.synth.groundtruth import DepthWriter
    from pipeline.synth.kitti360_write import KITTI_CAMERAS

    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("depth", "images.parquet"))
    names = dict(zip(cameras, KITTI_CAMERAS, strict=False))
    images = pq.read_table(src / "images.parquet")
    cams = images.column("camera").to_pylist()
    images = images.set_column(images.schema.get_field_index("camera"), "camera",
                               pa.array([names.get(c, c) for c in cams], pa.string()))
    pq.write_table(images, dst / "images.parquet")
    calib = json.loads((src / "calibration.json").read_text())["cameras"]
    for cam, name in names.items():
        depth = zarr.open_array(str(src / "depth" / f"{cam}.zarr"), mode="r")
        c = calib[cam]
        K, D = np.asarray(c["K"], np.float64), np.asarray(c["D"], np.float64).reshape(1, 4)
        size = (int(c["width"]), int(c["height"]))
        K_rect = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K, D, size, np.eye(3),
                                                                        balance=0.0)
        maps = cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), K_rect, size, cv2.CV_32FC1)
        out = DepthWriter(dst / "depth", {name: depth.shape[0]}, size[1], size[0])
        for i in range(depth.shape[0]):
            raw = np.asarray(depth[i], np.float32)
            out.write(name, i, np.asarray(cv2.remap(raw, maps[0], maps[1], cv2.INTER_NEAREST),
                                          np.float32))


def source_truth(name: str, cameras: list[str]) -> Any:
    """The decisions `m3gd inspect` must make on source variant `name` (`Truth`): an MCAP
    export's are the default bags' (`bench.variants_rig.decision_truth`); the KITTI-360 layout
    leaves none to make (poses.txt is the pose, velodyne_points the one LiDAR, image_0N the
    cameras' frames): its inspection must list none."""
    from bench.variants_rig import decision_truth
    from pipeline.synth.variants_tf import Truth

    if name == "kitti360":
        return Truth({}, False, (), {})
    return decision_truth("default", cameras)


def written_time(name: str, bags: tuple[str, str, str]) -> tuple[str, str, str]:
    """The point-time convention (field, unit, reference) variant `name`'s recording carries,
    as ingest records it in the sweeps table: the bags' (`bags`) for every variant but
    `kitti360`, whose `.bin` sweeps carry no point time (field, unit and reference empty:
    every point at its sweep's timestamps.txt stamp, stated by the layout, never inferred)."""
    return ("", "", "") if name == "kitti360" else bags


CELLS_TABLE = "_cells_table"
"""A row's key for its accuracy table (per-cell packet depths; removed by
`packets_vs_default`)."""
SAME_GEOMETRY = ("mcap_ros1", "mcap_ros2")
"""Source variants holding the bags' very messages: their packets must equal the default's.
(KITTI-360's images are rectified copies and its poses 10 Hz samples: its geometry is not the
bags', its depth abs-rel is compared instead.)"""


def _gap(a: float | None, b: float | None) -> float:
    """|a - b| (m) of two cells' depths; 0 when both are empty (null), inf when one is."""
    if a is None or b is None:
        return 0.0 if a is b else float("inf")
    return abs(float(a) - float(b))


def packets_vs_default(rows: list[dict[str, Any]]) -> dict[str, float | None]:
    """Per `SAME_GEOMETRY` row that ran, the largest |packet depth - the default's| (m) over
    the cells (camera, frame, row, col) of their accuracy tables (`CELLS_TABLE`; None where a
    cell of either is missing from the other, so a lost cell shows); stored in the row as
    `packets_max_diff_vs_default_m`. Every row's `CELLS_TABLE` key is removed."""
    import pyarrow.parquet as pq

    def cells(path: Any) -> dict[tuple[Any, ...], float]:
        if path is None:
            return {}
        t = pq.read_table(path, columns=["camera", "frame", "row", "col", "depth_m"])
        return {(c, f, r, k): d for c, f, r, k, d in zip(*(t.column(i).to_pylist()
                                                           for i in range(5)), strict=True)}

    paths = {r["variant"]: r.pop(CELLS_TABLE, None) for r in rows}
    ref = cells(paths.get("default"))
    out: dict[str, float | None] = {}
    for r in rows:
        if r["variant"] not in SAME_GEOMETRY or "refused" in r or not ref:
            continue
        got = cells(paths[r["variant"]])
        diff = (max((_gap(got[k], v) for k, v in ref.items()), default=0.0)
                if got.keys() == ref.keys() else None)
        out[r["variant"]] = r["packets_max_diff_vs_default_m"] = diff
    return out
