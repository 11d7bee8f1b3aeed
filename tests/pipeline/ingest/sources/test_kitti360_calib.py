"""The KITTI-360 text and binary parsers on hand-written files in the release's formats."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.ingest.sources.kitti360_calib import (
    parse_cam_to_pose,
    parse_perspective,
    parse_poses,
    parse_rigid_file,
    parse_stamp,
    parse_timestamps,
    parse_velodyne,
)
from schemas.errors import DataError

# the shape of the release's perspective.txt: raw-camera keys beside the rectified ones
PERSPECTIVE = """calib_time: 09-Jan-2015 14:48:23
corner_dist: 9.950000e-02
S_00: 1.392000e+03 5.120000e+02
K_00: 7.88e+02 0.0 6.87e+02 0.0 7.86e+02 3.17e+02 0.0 0.0 1.0
D_00: -3.4e-01 1.6e-01 4.0e-04 -6.7e-04 -4.3e-02
R_00: 1.0 0.0 0.0 0.0 1.0 0.0 0.0 0.0 1.0
T_00: 0.0 0.0 0.0
S_rect_00: 1.408000e+03 3.760000e+02
R_rect_00: 0.999974 -0.007141 -0.000089 0.007141 0.999969 -0.003247 0.000112 0.003247 0.999995
P_rect_00: 5.528000e+02 0.000000e+00 6.820000e+02 0.000000e+00 0.000000e+00 5.528000e+02 \
2.380000e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00
S_rect_01: 1.408000e+03 3.760000e+02
R_rect_01: 1.0 0.0 0.0 0.0 1.0 0.0 0.0 0.0 1.0
P_rect_01: 5.528000e+02 0.000000e+00 6.820000e+02 -3.258e+02 0.000000e+00 5.528000e+02 \
2.380000e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00
""".replace("\\\n", "")


def test_stamps_are_exact_nanoseconds() -> None:
    text = "2013-05-28 08:46:02.904069733\n2013-05-28 08:46:03.007000000\n\n"
    t = parse_timestamps(text, "timestamps.txt")
    assert t.dtype == np.int64
    # 2013-05-28 00:00:00 UTC = 1369699200 s; digits kept, no float on the way
    assert t[0] == (1369699200 + 8 * 3600 + 46 * 60 + 2) * 10**9 + 904_069_733
    assert t[1] - t[0] == 102_930_267
    assert parse_stamp("1970-01-01 00:00:00.5", "x") == 500_000_000  # short fraction padded
    with pytest.raises(DataError, match=r"velo/timestamps.txt line 2: '2013-05-28 8:46'"):
        parse_timestamps("2013-05-28 08:46:02.9\n2013-05-28 8:46\n", "velo/timestamps.txt")
    with pytest.raises(DataError, match="not a valid date"):
        parse_stamp("2013-13-28 08:46:02.9", "t.txt")


def test_perspective_cameras() -> None:
    cams = parse_perspective(PERSPECTIVE, "calibration/perspective.txt")
    assert sorted(cams) == ["image_00", "image_01"]
    c0 = cams["image_00"]
    assert (c0.width, c0.height) == (1408, 376)
    np.testing.assert_array_equal(c0.K, [[552.8, 0, 682], [0, 552.8, 238], [0, 0, 1]])
    assert c0.P_rect.shape == (3, 4) and c0.R_rect[0, 1] == -0.007141
    assert cams["image_01"].P_rect[0, 3] == -325.8  # the stereo baseline term
    broken = PERSPECTIVE.replace("S_rect_01", "X_rect_01")
    with pytest.raises(DataError, match=r"perspective.txt: no S_rect_01 line"):
        parse_perspective(broken, "calibration/perspective.txt")
    with pytest.raises(DataError, match=r"line 10 \(P_rect_00\): 11 numbers, expected 12"):
        parse_perspective(PERSPECTIVE.replace(" 1.000000e+00 0.000000e+00\nS_rect_01",
                                              " 1.000000e+00\nS_rect_01", 1), "perspective.txt")


def test_rigid_files() -> None:
    T = parse_rigid_file("0 0 1 0.1\n-1 0 0 0.2\n0 -1 0 0.3\n", "calib_cam_to_velo.txt")
    assert T.shape == (4, 4) and T[3].tolist() == [0, 0, 0, 1]
    np.testing.assert_array_equal(T @ [0, 0, 1, 1], [1.1, 0.2, 0.3, 1])  # cam z -> velo x
    rows = "image_00: 1 0 0 1 0 1 0 2 0 0 1 3\nimage_01: 1 0 0 4 0 1 0 5 0 0 1 6\n"
    to_pose = parse_cam_to_pose(rows, "calib_cam_to_pose.txt")
    assert to_pose["image_01"][:3, 3].tolist() == [4, 5, 6]
    with pytest.raises(DataError, match=r"calib_cam_to_velo.txt: the rotation is not orthonormal"):
        parse_rigid_file("2 0 0 0 0 1 0 0 0 0 1 0", "calib_cam_to_velo.txt")
    with pytest.raises(DataError, match=r"calib_cam_to_velo.txt: 11 numbers, expected 12"):
        parse_rigid_file("1 0 0 0 0 1 0 0 0 0 1", "calib_cam_to_velo.txt")


def test_poses_only_for_some_frames() -> None:
    text = "3 1 0 0 1 0 1 0 2 0 0 1 3\n7 0 -1 0 4 1 0 0 5 0 0 1 6\n"
    frames, T = parse_poses(text, "poses.txt")
    assert frames.tolist() == [3, 7] and T.shape == (2, 4, 4)
    assert T[1][:3, 3].tolist() == [4, 5, 6] and T[1][0, 1] == -1
    cam = "5 1 0 0 1 0 1 0 2 0 0 1 3 0 0 0 1\n"
    assert parse_poses(cam, "cam0_to_world.txt", width=16)[0].tolist() == [5]
    with pytest.raises(DataError, match=r"poses.txt line 2: frame 3 does not follow frame 7"):
        parse_poses("7 1 0 0 1 0 1 0 2 0 0 1 3\n3 1 0 0 1 0 1 0 2 0 0 1 3\n", "poses.txt")
    with pytest.raises(DataError, match=r"cam0_to_world.txt line 1: last row"):
        parse_poses("5 1 0 0 1 0 1 0 2 0 0 1 3 0 0 1 1\n", "cam0_to_world.txt", width=16)


def test_velodyne_bin() -> None:
    pts = np.array([[1.5, -2.0, 0.25, 0.7], [np.nan, 0, 0, 0.1]], dtype="<f4")
    xyz, refl = parse_velodyne(pts.tobytes(), "0000000000.bin")
    assert xyz.shape == (2, 3) and xyz[0].tolist() == [1.5, -2.0, 0.25]
    assert refl.dtype == np.float32 and np.isnan(xyz[1, 0])
    with pytest.raises(DataError, match=r"0000000001.bin: 20 bytes is not a whole number"):
        parse_velodyne(pts.tobytes()[:20], "0000000001.bin")
