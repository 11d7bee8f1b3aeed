"""The KITTI-360 raw layout: where its files are, and its calibration (the source itself:
`kitti360.Kitti360Source`; its pass: `kitti360_read`; its inspection: `kitti360_inspect`).

A recording is a KITTI-360 root holding one sequence `<seq>`:
`data_2d_raw/<seq>/image_00|01/{data_rect/NNNNNNNNNN.png, timestamps.txt}`,
`data_3d_raw/<seq>/velodyne_points/{data/NNNNNNNNNN.bin, timestamps.txt}`,
`data_poses/<seq>/poses.txt` and `calibration/{perspective.txt, calib_cam_to_velo.txt,
calib_cam_to_pose.txt}` (file formats: `kitti360_calib`). Frame i of a sensor folder is line i
of its timestamps.txt and file i of its data folder; poses.txt frames index `image_00`'s frames.

Frames and transforms (the reading of kitti360Scripts' `helpers/project.py`): the `pose` frame
of poses.txt is the configured base frame (`ingest.topics.base_frame`), `world` the odometry
frame. A rectified camera NN is at T_base_cam = T_pose_camNN . inv(R_rect_NN); the Velodyne at
T_base_velo = T_pose_cam00 . inv(T_velo_cam00). Configured cameras are the folders `image_00`,
`image_01` when so named, else taken in order (the first configured camera is `image_00`).
The images are already rectified pinhole images: K = P_rect's left 3x3, no distortion.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from packets.poses import F64, invert_T
from pipeline.ingest.calib.camera import RawCamera, build_rectifier
from pipeline.ingest.checks.rejects import Reject
from pipeline.ingest.sources.kitti360_calib import (
    parse_cam_to_pose,
    parse_perspective,
    parse_rigid_file,
)
from pipeline.ingest.sources.static import StaticCalib
from schemas.config import IngestConfig
from schemas.errors import DataError
from schemas.recording_index import Reason

FORMAT = "kitti360"
CAMERA_FOLDERS = ("image_00", "image_01")
VELODYNE = "velodyne_points"
PARTS = ("data_2d_raw", "data_3d_raw", "data_poses", "calibration")
CALIB_FILES = ("perspective.txt", "calib_cam_to_pose.txt", "calib_cam_to_velo.txt")


def is_kitti360(folder: Path) -> bool:
    """Whether `folder` looks like a KITTI-360 root (its raw 2D and 3D data and calibration)."""
    return all((folder / p).is_dir() for p in ("data_2d_raw", "data_3d_raw", "calibration"))


@dataclass(frozen=True)
class Kitti360Layout:
    """Paths of one sequence of a KITTI-360 root."""

    root: Path
    seq: str

    @classmethod
    def open(cls, root: Path) -> Kitti360Layout:
        """The layout of `root`'s one sequence; DataError naming what is missing or ambiguous."""
        missing = [p for p in PARTS if not (root / p).is_dir()]
        if missing:
            raise DataError(f"{root}: not a KITTI-360 root: no folder {', '.join(missing)} "
                            f"(expected {', '.join(PARTS)})")  # fmt: skip
        seqs = sorted(p.name for p in (root / "data_3d_raw").iterdir() if p.is_dir())
        if len(seqs) != 1:
            raise DataError(f"{root / 'data_3d_raw'}: {len(seqs)} sequences "
                            f"({', '.join(seqs) or 'none'}); a recording is one sequence: "
                            "give each its own root")  # fmt: skip
        return cls(root, seqs[0])

    def rel(self, path: Path) -> str:
        """`path` relative to the root (the `file` of index and reject rows)."""
        return str(path.relative_to(self.root))

    def sensor_dir(self, name: str) -> Path:
        """The folder of `image_0N` or `velodyne_points`."""
        part = "data_3d_raw" if name == VELODYNE else "data_2d_raw"
        return self.root / part / self.seq / name

    def frame_file(self, name: str, frame: int) -> Path:
        """Frame `frame`'s file: a data_rect PNG or a velodyne .bin."""
        if name == VELODYNE:
            return self.sensor_dir(name) / "data" / f"{frame:010d}.bin"
        return self.sensor_dir(name) / "data_rect" / f"{frame:010d}.png"

    @property
    def poses(self) -> Path:
        """data_poses/<seq>/poses.txt."""
        return self.root / "data_poses" / self.seq / "poses.txt"

    def text(self, path: Path, what: str) -> str:
        """The text of a layout file; DataError naming it (and what it holds) when absent."""
        try:
            return path.read_text()
        except FileNotFoundError as err:
            raise DataError(f"{self.rel(path)}: no such file ({what})") from err

    def calib(self, name: str) -> str:
        """The text of calibration/<name>."""
        return self.text(self.root / "calibration" / name, "KITTI-360 calibration")


def camera_folders(cameras: list[str]) -> dict[str, str]:
    """Configured camera -> KITTI-360 folder: its own name when that is a folder name, else the
    folders in configuration order; DataError for more cameras than folders."""
    if len(cameras) > len(CAMERA_FOLDERS):
        raise DataError(f"ingest.cameras {cameras}: KITTI-360 has {len(CAMERA_FOLDERS)} "
                        f"perspective cameras ({', '.join(CAMERA_FOLDERS)})")  # fmt: skip
    if all(c in CAMERA_FOLDERS for c in cameras):
        return {c: c for c in cameras}
    return dict(zip(cameras, CAMERA_FOLDERS, strict=False))


def rect_to_base(T_pose_cam: F64, R_rect: F64) -> F64:
    """T_base_rectcam (4, 4) = T_pose_cam . inv(R_rect) (R_rect (3, 3) maps camera -> rectified)."""
    R4 = np.eye(4)
    R4[:3, :3] = R_rect
    return np.asarray(T_pose_cam @ R4.T, dtype=np.float64)


def read_kitti360_static(layout: Kitti360Layout, cfg: IngestConfig) -> StaticCalib:
    """TF tree (base -> cameras, LiDAR) and pinhole camera + rectifier per configured camera;
    a camera without P_rect or calib_cam_to_pose row is a reject, a broken file an error."""
    persp = parse_perspective(layout.calib("perspective.txt"), "calibration/perspective.txt")
    to_pose = parse_cam_to_pose(layout.calib("calib_cam_to_pose.txt"),
                                "calibration/calib_cam_to_pose.txt")  # fmt: skip
    T_velo_cam0 = parse_rigid_file(layout.calib("calib_cam_to_velo.txt"),
                                   "calibration/calib_cam_to_velo.txt")  # fmt: skip
    if "image_00" not in to_pose:
        raise DataError("calibration/calib_cam_to_pose.txt: no image_00 line: the Velodyne is "
                        "placed through camera 0 (calib_cam_to_velo.txt)")  # fmt: skip
    base, calib = cfg.topics.base_frame, StaticCalib()
    lidar = cfg.topics.lidar_rig()[0]
    calib.tf.add(base, lidar.frame, to_pose["image_00"] @ invert_T(T_velo_cam0))
    for cam, folder in camera_folders(cfg.cameras).items():
        if folder not in persp or folder not in to_pose:
            where = "perspective.txt" if folder not in persp else "calib_cam_to_pose.txt"
            calib.rejects.append(Reject(f"calibration/{where}", folder, 0,
                                        Reason.MISSING_CAMERA_INFO,
                                        f"calibration/{where} has no {folder} entry; images of "
                                        f"camera '{cam}' are not ingested"))  # fmt: skip
            continue
        p, frame = persp[folder], cfg.topics.frame_of(cam)
        calib.tf.add(base, frame, rect_to_base(to_pose[folder], p.R_rect))
        raw = RawCamera(cam, frame, p.width, p.height, "pinhole", p.K, np.zeros(5))
        calib.cameras[cam] = raw
        calib.rectifiers[cam] = build_rectifier(raw, (cfg.out_height, cfg.out_width),
                                                balance=cfg.rectify_balance,
                                                reduced=cfg.reduced_decode)  # fmt: skip
    return calib


IDENTITY_NAMES = frozenset({"timestamps.txt", "poses.txt", "cam0_to_world.txt", "data_rect",
                            "data"})  # fmt: skip
"""Files (and the data folders, whose size and mtime change with their files) keying a cache."""


def identifies(name: str) -> bool:
    """Whether a listing name is one of a sequence's identity names (`IDENTITY_NAMES`)."""
    parts = name.rstrip("/").split("/")
    if parts[0] == "calibration":
        return len(parts) == 2 and parts[1] in CALIB_FILES
    return parts[0] in PARTS[:3] and parts[-1] in IDENTITY_NAMES and len(parts) in (3, 4, 5)


