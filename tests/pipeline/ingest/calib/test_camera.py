"""Rectifier: one map equals fisheye projection of the output pinhole rays; K_out follows crops."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from bench.decode_choice import measure_choices, psnr, reference_rectify
from pipeline.ingest.calib.camera import (
    CorruptImageError,
    RawCamera,
    build_rectifier,
    camera_from_info,
    check_jpeg,
    choose_reduction,
    crop_resize_K,
    output_K,
    raw_map,
)

K_BIG = np.array([[900.0, 0, 959.5], [0, 900.0, 639.5], [0, 0, 1]])
D_BIG = np.array([-0.03, 0.004, -0.002, 0.0005])


def _cam(w: int = 1920, h: int = 1280, K: np.ndarray = K_BIG) -> RawCamera:
    return RawCamera("front", "hdr_front", w, h, "equidistant", K, D_BIG)


def test_map_is_fisheye_projection_of_output_rays() -> None:
    cam = _cam()
    out_hw = (224, 336)
    K_out = output_K(cam, out_hw, 0.0)
    mx, my = raw_map(cam, K_out, out_hw)
    v, u = np.mgrid[0:224:17, 0:336:23]
    rays = np.linalg.solve(K_out, np.stack([u.ravel(), v.ravel(), np.ones(u.size)]).astype(float))
    pix, _ = cv2.fisheye.projectPoints(rays.T[None].astype(np.float64), np.zeros(3), np.zeros(3),
                                        cam.K, cam.D)  # fmt: skip
    np.testing.assert_allclose(mx[v, u].ravel(), pix[0, :, 0], atol=2e-3)
    np.testing.assert_allclose(my[v, u].ravel(), pix[0, :, 1], atol=2e-3)


def test_crop_resize_K_maps_pixel_edges_to_edges() -> None:
    K = np.array([[100.0, 0, 47.0], [0, 100.0, 40.0], [0, 0, 1]])
    out = crop_resize_K(K, (80, 96), (28, 42))  # 6:5 -> 3:2: crop height to 64 (y0 = 8)

    def to_out(u: float, v: float) -> tuple[float, float]:
        x, y = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
        return out[0, 0] * x + out[0, 2], out[1, 1] * y + out[1, 2]

    np.testing.assert_allclose(to_out(-0.5, 7.5), (-0.5, -0.5), atol=1e-12)
    np.testing.assert_allclose(to_out(95.5, 71.5), (41.5, 27.5), atol=1e-12)


def test_reduction_choice_follows_output_scale() -> None:
    cam = _cam()
    assert choose_reduction(cam, output_K(cam, (224, 336), 0.0), True) == 4
    assert choose_reduction(cam, output_K(cam, (224, 336), 0.0), False) == 1
    small = _cam(480, 320, K_BIG / np.array([[4], [4], [1]]))
    assert choose_reduction(small, output_K(small, (224, 336), 0.0), True) == 1


def _scene(w: int, h: int) -> bytes:
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    img = np.stack([128 + 100 * np.sin(xx / 37.0), 128 + 100 * np.cos(yy / 29.0),
                    128 + 80 * np.sin((xx + yy) / 53.0)], -1)  # fmt: skip
    ok, buf = cv2.imencode(".jpg", img.astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return buf.tobytes()


def test_one_remap_matches_the_three_step_reference() -> None:
    cam = _cam(960, 640, K_BIG / np.array([[2], [2], [1]]))
    jpeg = _scene(960, 640)
    ref = reference_rectify(jpeg, cam, (224, 336), 0.0)
    for r in (1, 2):
        out = build_rectifier(cam, (224, 336), reduction=r).apply(jpeg, "test")
        assert out.shape == (224, 336, 3) and out.dtype == np.uint8
        assert psnr(out, ref) > 30.0, r
    rows = measure_choices([jpeg], cam, (224, 336))
    assert sum(bool(r["default"]) for r in rows) == 1
    assert all(r["ms_per_image"] > 0 for r in rows)


def test_corrupt_and_cut_jpeg_are_refused() -> None:
    cam = _cam(96, 64, np.array([[40.0, 0, 47.5], [0, 40.0, 31.5], [0, 0, 1]]))
    rect = build_rectifier(cam, (28, 42))
    jpeg = _scene(96, 64)
    with pytest.raises(CorruptImageError, match="cut short"):
        rect.apply(jpeg[: len(jpeg) // 2], "f.bag: /img at 5")
    with pytest.raises(CorruptImageError, match="not a JPEG"):
        rect.apply(b"\x00" * 100, "f.bag: /img at 5")
    with pytest.raises(CorruptImageError, match=r"f\.bag: /img at 5: empty image payload"):
        rect.apply(b"", "f.bag: /img at 5")
    with pytest.raises(CorruptImageError, match="CameraInfo size 96x64"):
        rect.apply(_scene(64, 48), "f.bag: /img at 5")


def test_camera_info_ros1_and_ros2_names() -> None:
    hdr = SimpleNamespace(frame_id="/hdr_front")
    ros1 = SimpleNamespace(distortion_model="equidistant", K=K_BIG.ravel(), D=D_BIG, width=1920,
                           height=1280, header=hdr)  # fmt: skip
    ros2 = SimpleNamespace(distortion_model="equidistant", k=K_BIG.ravel(), d=D_BIG, width=1920,
                           height=1280, header=hdr)  # fmt: skip
    a, b = camera_from_info("front", ros1, "x"), camera_from_info("front", ros2, "x")
    np.testing.assert_array_equal(a.K, b.K)
    assert a.frame_id == "hdr_front"
    bad = SimpleNamespace(**{**vars(ros1), "distortion_model": "weird"})
    with pytest.raises(ValueError, match="unsupported distortion model 'weird'"):
        camera_from_info("front", bad, "x")


def _photo(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A textured image: smooth gradients plus noise, so every JPEG byte value occurs."""
    yy, xx = np.mgrid[0:h, 0:w]
    base = np.stack([xx * 255 / w, yy * 255 / h, (xx + yy) % 256], axis=-1)
    return np.clip(base + rng.normal(0, 40, (h, w, 3)), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("params", [
    [], [cv2.IMWRITE_JPEG_PROGRESSIVE, 1], [cv2.IMWRITE_JPEG_RST_INTERVAL, 4],
    [cv2.IMWRITE_JPEG_OPTIMIZE, 1], [cv2.IMWRITE_JPEG_QUALITY, 100],
    [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_411]])
def test_well_formed_jpegs_of_every_kind_pass(params: list[int]) -> None:
    rng = np.random.default_rng(len(params))
    for h, w in ((64, 96), (131, 77), (320, 480)):
        ok, enc = cv2.imencode(".jpg", _photo(rng, h, w), params)
        assert ok
        check_jpeg(enc.ravel(), "f.bag: /img at 5")


def test_random_bytes_inside_the_image_data_are_refused() -> None:
    rng = np.random.default_rng(3)
    ok, enc = cv2.imencode(".jpg", _photo(rng, 320, 480))
    assert ok
    good = enc.ravel()
    for seed in range(20):  # 4 KB of garbage, like a damaged disk block (~16 0xFF bytes)
        bad = good.copy()
        at = len(bad) // 3 + 37 * seed
        bad[at:at + 4096] = np.random.default_rng(seed).integers(0, 256, 4096, dtype=np.uint8)
        with pytest.raises(CorruptImageError, match=r"f\.bag: /img at 5: JPEG data corrupt"):
            check_jpeg(bad, "f.bag: /img at 5")
        # libjpeg itself decodes such data without an error: the check is what refuses it
        assert cv2.imdecode(bad, cv2.IMREAD_COLOR) is not None
