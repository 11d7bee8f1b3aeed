"""Motion variety (speed swing, turning) and the injected camera clock offset."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.synth.api import synthesize
from pipeline.synth.trajectory import Motion, PathSpec, Trajectory
from schemas.config import SynthConfig
from tests.pipeline.synth.helpers import table

LINE = PathSpec("line", 100.0, 10.0, 0.0, 10.0)  # straight along x: speed = ds/dt exactly


def _yaw(T: np.ndarray) -> np.ndarray:
    return np.arctan2(T[:, 1, 0], T[:, 0, 0])  # exact for R = Rz(yaw) Ry(pitch) Rx(roll)


def test_speed_follows_the_profile_in_closed_form() -> None:
    m = Motion(speed_variation=0.6, speed_period_s=4.0)
    traj = Trajectory(LINE, 1.2, 0.0, m)
    t = np.linspace(0.0, 8.0, 33)
    h = 1e-4
    speed = (traj.poses(t + h)[:, 0, 3] - traj.poses(t - h)[:, 0, 3]) / (2 * h)
    np.testing.assert_allclose(speed, 1.2 * (1 + 0.6 * np.sin(2 * np.pi * t / 4.0)), atol=1e-6)
    np.testing.assert_allclose(traj.poses(t)[:, 0, 3], m.arc(1.2, t), atol=1e-12)
    stop = Trajectory(LINE, 1.0, 0.0, Motion(1.0, 4.0))  # a = 1: comes to a stop, never back
    assert np.all(np.diff(stop.poses(np.linspace(0, 8, 400))[:, 0, 3]) >= -1e-12)


def test_turning_adds_yaw_rate_peaking_at_the_configured_rate() -> None:
    base = Trajectory(LINE, 1.0, 0.3)
    turn = Trajectory(LINE, 1.0, 0.3, Motion(yaw_rate_max_rps=1.0, yaw_period_s=6.0))
    t = np.linspace(0.0, 6.0, 61)
    h = 1e-4
    extra = [(_yaw(tr.poses(t + h)) - _yaw(tr.poses(t - h))) / (2 * h) for tr in (turn, base)]
    np.testing.assert_allclose(extra[0] - extra[1], np.cos(2 * np.pi * t / 6.0), atol=1e-6)
    assert np.max(np.abs(extra[0] - extra[1])) == pytest.approx(1.0, abs=1e-6)
    _, w = turn.twist(np.array([0.0]))  # body yaw rate at t = 0: 1 rad/s plus the gait wobble
    assert w[0, 2] == pytest.approx(extra[0][0], abs=0.05)


def test_default_motion_is_the_constant_walk() -> None:
    t = np.linspace(-1, 5, 13)
    a = Trajectory(LINE, 0.8, 1.0).poses(t)
    np.testing.assert_array_equal(a, Trajectory(LINE, 0.8, 1.0, Motion()).poses(t))
    np.testing.assert_allclose(a[:, 0, 3], 0.8 * t, atol=1e-12)


def test_clock_offset_shifts_stamps_not_captures(tmp_path: Path) -> None:
    small = {"seconds": 0.6, "image_width": 96, "image_height": 64, "points_per_sweep": 256,
             "cameras": ["front"], "depth_maps": False}
    plain = synthesize(tmp_path / "a", SynthConfig(**small), "corridor")
    late = synthesize(tmp_path / "b", SynthConfig(**small, camera_clock_offset_s=0.045),
                      "corridor")
    a, b = table(plain.groundtruth_dir, "images"), table(late.groundtruth_dir, "images")
    np.testing.assert_array_equal(a["stamp_ns"], b["stamp_ns"])  # same capture times
    np.testing.assert_array_equal(np.subtract(b["header_stamp_ns"], b["stamp_ns"]), 45_000_000)
    np.testing.assert_array_equal(np.subtract(b["bag_time_ns"], b["stamp_ns"]), 45_000_000)
    scene = json.loads((late.groundtruth_dir / "scene.json").read_text())
    assert scene["camera_clock_offset_ns"] == 45_000_000
    assert scene["trajectory"]["yaw_rate_max_rps"] == 0.0
