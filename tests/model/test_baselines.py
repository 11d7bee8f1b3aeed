"""The mean-image baselines: closed forms on a cache whose images are known exactly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from model.baselines import build_mean_images, strided, to_uint8
from model.dataset import load_clips
from model.evaluate import TargetResult, image_scores, reference_scores
from model.scoring import _means
from tests.model.cache_fixture import N, build_cache


def _image(rec: str, f: int, shape: tuple[int, ...]) -> np.ndarray:
    """A view's image: a vertical ramp (layout) plus a per-view offset."""
    h = shape[0]
    ramp = np.linspace(0, 120, h)[:, None, None] * np.ones(shape[1:])
    return (ramp + 3 * f + (60 if rec == "r1" else 0)).astype(np.uint8)


def _fill(rec: str, _cam: str, arrays: dict[str, np.ndarray]) -> None:
    imgs = arrays["images"]
    for f in range(N):
        imgs[f] = _image(rec, f, imgs.shape[1:])


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("baselines")
    build_cache(out, ("r0", "r1"), ("front",), fill=_fill)  # r0: training, r1: eval
    return out


def _all(rec: str, frames: list[int], shape: tuple[int, ...]) -> np.ndarray:
    return np.stack([_image(rec, f, shape) for f in frames]).astype(np.float64)


def test_mean_image_is_the_mean_of_the_training_views(cache: Path) -> None:
    means = build_mean_images(cache, ["r1/front"])
    shape = means.train_mean.shape
    train = sorted({f for c in load_clips(cache, "train") for f in c["frames"]})
    assert train == list(range(N))
    np.testing.assert_allclose(means.train_mean, _all("r0", train, shape).mean(0))
    assert means.train_views == N


def test_eval_recording_has_no_recording_mean_but_an_oracle(cache: Path) -> None:
    """Recording-level split: no training view in r1, so no fair recording mean; the
    oracle averages r1's views outside the clip."""
    means = build_mean_images(cache, ["r1/front"])
    clip = load_clips(cache, "eval")[0]
    shape = means.train_mean.shape
    imgs = _all("r1", list(clip["frames"]), shape).astype(np.uint8)
    refs = means.references(clip, imgs)
    assert "recording_mean" not in refs
    others = [f for f in range(N) if f not in clip["frames"]]
    np.testing.assert_array_equal(refs["recording_mean_oracle"],
                                  to_uint8(_all("r1", others, shape).mean(0)))
    np.testing.assert_array_equal(refs["mean_image"], to_uint8(means.train_mean))


def test_recording_mean_leaves_the_clips_own_views_out(cache: Path) -> None:
    """Where a recording's other views are training views (a training clip of r0 here),
    the recording mean averages them, without the clip's own views."""
    means = build_mean_images(cache, ["r0/front"])
    clip = load_clips(cache, "train")[3]
    shape = means.train_mean.shape
    imgs = _all("r0", list(clip["frames"]), shape).astype(np.uint8)
    refs = means.references(clip, imgs)
    others = [f for f in range(N) if f not in clip["frames"]]
    np.testing.assert_array_equal(refs["recording_mean"],
                                  to_uint8(_all("r0", others, shape).mean(0)))


def test_no_training_view_is_an_error(cache: Path) -> None:
    with pytest.raises(ValueError, match="no training view"):
        build_mean_images(cache, ["r0/front"], train_recordings={"elsewhere"})


def test_reference_scores_match_direct_scoring() -> None:
    rng = np.random.default_rng(0)
    gt = rng.integers(0, 256, (3, 16, 16, 3), dtype=np.uint8)
    a, b = (rng.integers(0, 256, (16, 16, 3), dtype=np.uint8) for _ in range(2))
    refs = [{"mean_image": a, "recording_mean": b}, {"mean_image": a}]
    out = reference_scores(refs, [0, 1, 1], gt)
    p, s = image_scores(np.stack([a, a, a]), gt)
    for k in range(3):
        assert out[k]["mean_image"] == (pytest.approx(p[k]), pytest.approx(s[k]))
    assert "recording_mean" in out[0] and "recording_mean" not in out[1]


def _result(psnr: float, ssim: float, base: dict[str, tuple[float, float]]) -> TargetResult:
    return TargetResult(0, 1, None, None, psnr, ssim, base)


def test_margin_is_against_the_strongest_fair_baseline() -> None:
    """The oracle never sets the bar; PSNR and SSIM margins may name different baselines;
    a baseline some target lacks is left out of the means."""
    base = {"copy_source": (15.0, 0.20), "mean_latent": (14.0, 0.33),
            "mean_image": (16.0, 0.30), "recording_mean_oracle": (30.0, 0.90)}
    out = _means([_result(17.0, 0.25, base),
                  _result(17.0, 0.25, {**base, "recording_mean": (40.0, 0.9)})])
    assert out["better_baseline"] == "mean_image"
    assert out["margin_db"] == pytest.approx(1.0)
    assert out["strongest_ssim_baseline"] == "mean_latent"
    assert out["ssim_margin"] == pytest.approx(-0.08)
    assert "recording_mean" not in out["baselines"]
    assert "recording_mean_oracle" in out["baselines"]


def test_the_strongest_baseline_is_the_best_of_every_baseline_scored() -> None:
    """The LiDAR reprojection above copy-source is the strongest; the oracle never is."""
    base = {"copy_source": (15.0, 0.40), "mean_latent": (14.0, 0.33),
            "reprojection": (16.5, 0.35), "recording_mean_oracle": (30.0, 0.90)}
    out = _means([_result(16.0, 0.38, base)])
    assert out["better_baseline"] == "copy_source"  # the image-only bar is unchanged
    assert out["strongest_baseline"] == "reprojection"
    assert out["margin_strongest_db"] == pytest.approx(-0.5)
    assert out["strongest_baseline_by_ssim"] == "copy_source"
    assert out["ssim_margin_strongest"] == pytest.approx(-0.02)


def test_reprojection_consistency_means_over_the_targets_that_have_it() -> None:
    base = {"copy_source": (15.0, 0.20), "mean_latent": (14.0, 0.33)}
    scored = [TargetResult(0, 1, None, None, 17.0, 0.3, base,
                           {"model": m, "ground_truth": 0.2, "copy_source": 1.0,
                            "mean_latent": 1.1, "reprojection": 0.5}, points)
              for m, points in ((0.4, 3), (0.6, 5))]
    out = _means([*scored, _result(10.0, 0.1, base)])  # one target without a reprojection
    assert out["targets"] == 3 and out["reproj_targets"] == 2
    assert out["reproj_err"] == pytest.approx(0.5)
    assert out["reproj_err_baselines"] == pytest.approx(
        {"ground_truth": 0.2, "copy_source": 1.0, "mean_latent": 1.1, "reprojection": 0.5})
    assert out["reproj_points_mean"] == 4.0
    assert not any(k.startswith("reproj") for k in _means([_result(10.0, 0.1, base)]))


def test_strided_keeps_ends_and_limit() -> None:
    items = [("g", i) for i in range(10)]
    assert strided(items, 20) == items
    picked = strided(items, 4)
    assert len(picked) == 4 and picked[0] == ("g", 0) and picked[-1] == ("g", 9)
