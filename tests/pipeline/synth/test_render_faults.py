"""Rendered rig faults: the images come from a camera displaced (or turned) from where the
recording's calibration says it is, and the calibration is written unchanged."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.synth.api import synthesize
from pipeline.synth.camera import CameraRenderer
from pipeline.synth.rig import R_BODY_OPTICAL, FisheyeCamera
from pipeline.synth.scene import Primitive, Raycaster, Scene
from pipeline.synth.streams import camera_displacement, mounting_error, rendered_extrinsic
from pipeline.synth.trajectory import PathSpec
from schemas.config import SynthConfig
from tests.pipeline.synth.helpers import table

F_PX = 200.0
W, H = 320, 240
SMALL = {"image_width": 160, "image_height": 112, "points_per_sweep": 1024, "seconds": 0.6,
         "cameras": ["front"], "scenes": ["corridor"], "depth_maps": False}  # fmt: skip


def _wall_view(depth_m: float, offset_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(grey image, depth) of a textured wall `depth_m` ahead of an undistorted pinhole camera
    (f = F_PX) rendered from T @ camera_displacement((offset_m, 0, 0))."""
    cam = FisheyeCamera("c", "c", W, H, np.array([[F_PX, 0, W / 2 - 0.5], [0, F_PX, H / 2 - 0.5],
                                                  [0, 0, 1]]), np.zeros(5), "plumb_bob")
    wall = Primitive("box", "wall", (depth_m + 0.5, 0.0, 1.0), (1.0, 40.0, 20.0))
    scene = Scene("wall", 0, PathSpec("line", 1.0, 1.0, 0.0, 1.0), [wall])
    T = np.eye(4)
    T[:3, :3] = R_BODY_OPTICAL  # looking along +x (the wall's normal), 1 m up
    T[2, 3] = 1.0
    T = rendered_extrinsic(T, (0.0, 0.0, 0.0), (offset_m, 0.0, 0.0))
    frame = CameraRenderer(cam, Raycaster(scene)).render(T)
    return cv2.cvtColor(frame.bgr, cv2.COLOR_BGR2GRAY).astype(np.float64), frame.depth


@pytest.mark.parametrize("depth_m", [2.0, 4.0, 8.0])
def test_a_10cm_lateral_move_shifts_the_image_by_f_times_0_1_over_depth(depth_m: float) -> None:
    nominal, d0 = _wall_view(depth_m, 0.0)
    moved, d1 = _wall_view(depth_m, 0.10)
    np.testing.assert_allclose(d0, depth_m, rtol=1e-5)  # a fronto-parallel wall: one depth
    np.testing.assert_allclose(d1, depth_m, rtol=1e-5)  # a lateral move keeps it
    # the camera moved +x (right): the wall's content moves left by f * 0.1 / d pixels
    assert _shift_px(nominal, moved) == pytest.approx(-F_PX * 0.10 / depth_m, abs=0.1)
    assert _shift_px(nominal.T, moved.T) == pytest.approx(0.0, abs=0.1)  # none vertically


def _shift_px(a: np.ndarray, b: np.ndarray) -> float:
    """The horizontal shift s (px, 0.02 px steps within +-15) of content between images a and
    b (H, W): b(u) = a(u - s), the one that matches the central columns best."""
    u = np.arange(a.shape[1], dtype=np.float64)
    inner = slice(20, a.shape[1] - 20)
    steps = np.arange(-15.0, 15.0, 0.02)
    cost = [np.mean([np.abs(np.interp(u - s, u, ra) - rb)[inner].mean()
                     for ra, rb in zip(a[::4], b[::4], strict=True)]) for s in steps]
    return float(steps[int(np.argmin(cost))])


def test_displacement_and_rotation_are_exactly_the_calibration_at_zero() -> None:
    T = np.arange(16, dtype=np.float64).reshape(4, 4) / 7.0
    assert rendered_extrinsic(T, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)) is T
    E = camera_displacement((0.1, -0.2, 0.3))
    assert np.array_equal(E[:3, :3], np.eye(3)) and E[:3, 3].tolist() == [0.1, -0.2, 0.3]
    both = rendered_extrinsic(T, (0.0, 0.0, 2.0), (0.1, 0.0, 0.0))
    want = T @ camera_displacement((0.1, 0.0, 0.0)) @ mounting_error((0.0, 0.0, 2.0))
    assert np.array_equal(both, want)


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(clean mission, the same mission rendered with every camera 10 cm to its right)."""
    root = tmp_path_factory.mktemp("render_faults")
    cfg = SynthConfig(**SMALL)
    clean = synthesize(root / "a", cfg, "corridor", "m").mission_dir
    moved = synthesize(root / "b", cfg, "corridor", "m", camera_offset_m=(0.1, 0.0, 0.0))
    return clean, moved.mission_dir


def test_the_recording_declares_the_calibrated_camera(pair: tuple[Path, Path]) -> None:
    clean, moved = pair
    for name in ("m_tf_minimal.bag", "m_hesai_undist.bag", "m_anymal_state.bag"):
        assert (clean / name).read_bytes() == (moved / name).read_bytes(), name
    assert ((clean / "groundtruth" / "calibration.json").read_bytes()
            == (moved / "groundtruth" / "calibration.json").read_bytes())  # fmt: skip
    assert (clean / "m_hdr_front.bag").read_bytes() != (moved / "m_hdr_front.bag").read_bytes()
    stamps = [table(m / "groundtruth", "images")["stamp_ns"] for m in pair]
    assert stamps[0] == stamps[1] and stamps[0]
    scene = json.loads((moved / "groundtruth" / "scene.json").read_text())
    assert scene["camera_extrinsic_offset_m"] == [0.1, 0.0, 0.0]
    assert "camera_extrinsic_offset_m" not in json.loads(
        (clean / "groundtruth" / "scene.json").read_text())


def test_the_config_key_renders_what_the_argument_renders(
        pair: tuple[Path, Path], tmp_path: Path) -> None:
    cfg = SynthConfig(**SMALL, camera_extrinsic_offset_m=(0.1, 0.0, 0.0))
    keyed = synthesize(tmp_path, cfg, "corridor", "m").mission_dir
    _, moved = pair
    for name in ("m_hdr_front.bag", "m_tf_minimal.bag"):
        assert (keyed / name).read_bytes() == (moved / name).read_bytes(), name


def test_an_unset_offset_keeps_the_config_and_its_keys_as_before() -> None:
    """An unset displacement serializes (and so hashes and keys caches) as before the key
    existed; a set one is written; beyond +-1 m is refused."""
    assert "camera_extrinsic_offset_m" not in SynthConfig().model_dump(mode="json")
    set_ = SynthConfig(camera_extrinsic_offset_m=(0.0, 0.0, -0.05)).model_dump(mode="json")
    assert set_["camera_extrinsic_offset_m"] == [0.0, 0.0, -0.05]
    with pytest.raises(ValueError, match="camera_extrinsic_offset_m"):
        SynthConfig(camera_extrinsic_offset_m=(1.5, 0.0, 0.0))
