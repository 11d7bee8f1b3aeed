"""The streaming pass: a repeated CameraInfo is recognised from its bytes without decoding."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from pipeline.ingest.core.stream import CAMERA_INFO, _header_first, info_key
from pipeline.ingest.sources.bags import Message
from tests.pipeline.ingest.bagkit import D_RAW, K_RAW


def _info(ts: Any, stamp: int, seq: int = 0, fx: float = float(K_RAW[0, 0]),
          frame: str = "hdr_front") -> Any:  # fmt: skip
    """A CameraInfo of the test camera at `stamp` (ns)."""
    T = ts.types
    time = T["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
    fields = T["std_msgs/msg/Header"].__dataclass_fields__
    header = T["std_msgs/msg/Header"](**({"seq": seq} if "seq" in fields else {}), stamp=time,
                                      frame_id=frame)  # fmt: skip
    K = K_RAW.copy()
    K[0, 0] = fx
    roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                do_rectify=False)  # fmt: skip
    ci = T[CAMERA_INFO]
    names = {n.lower(): n for n in ci.__dataclass_fields__}  # ROS1 K, D, ...; ROS2 k, d, ...
    arrays = {"d": D_RAW.copy(), "k": K.ravel(), "r": np.eye(3).ravel(), "p": np.zeros(12)}
    return ci(header=header, height=480, width=640, distortion_model="equidistant",
              **{names[k]: v for k, v in arrays.items()}, binning_x=0, binning_y=0,
              roi=roi)  # fmt: skip


@pytest.mark.parametrize("ros2", [False, True])
def test_info_key_ignores_only_the_stamp(ros2: bool) -> None:
    ts = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    ser = ts.serialize_cdr if ros2 else ts.serialize_ros1
    bag = SimpleNamespace(ros2=ros2)

    def key(obj: Any) -> Any:
        msg = Message("b.bag", "/info", CAMERA_INFO, 0, 0, bytes(ser(obj, CAMERA_INFO)), "d")
        return info_key(bag, msg)  # type: ignore[arg-type]

    base = key(_info(ts, 1_717_000_000_000_000_000))
    assert key(_info(ts, 1_717_000_000_123_456_789, seq=7)) == base  # stamp and seq only
    assert key(_info(ts, 1_717_000_000_000_000_000, fx=301.0)) != base  # another K
    assert key(_info(ts, 1_717_000_000_000_000_000, frame="hdr_left")) != base
    assert _header_first(_info(ts, 0), ros2)
    assert not _header_first(_info(ts, 0), not ros2)
