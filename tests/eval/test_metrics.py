"""Image metrics against independent computations: analytic PSNR, skimage SSIM, brute-force SSIM
(tests/_ssim_reference.py)."""

import math

import numpy as np
import pytest
from _ssim_reference import brute_ssim_same
from skimage.metrics import structural_similarity

import strings_bench.eval.metrics as metrics
from strings_bench.core.errors import StringsBenchError


def _img(seed, h=40, w=48):
    rng = np.random.default_rng(seed)
    from scipy.ndimage import gaussian_filter

    x = gaussian_filter(rng.random((h, w, 3)), (2, 2, 0))
    return (x - x.min()) / (x.max() - x.min())


def test_psnr_analytic():
    gt = np.full((10, 12, 3), 0.5)
    img = gt + 0.1  # MSE = 0.01 -> 20 dB
    assert metrics.psnr(img, gt) == pytest.approx(20.0, abs=1e-9)
    img2 = gt.copy()
    img2[0, 0, 0] += 1.0  # one pixel off by 1: MSE = 1/360
    assert metrics.psnr(img2, gt) == pytest.approx(10 * math.log10(360), abs=1e-9)
    assert metrics.psnr(gt, gt) == math.inf


def test_ssim_identical_is_one_and_bounded():
    x = _img(0)
    assert metrics.ssim(x, x) == pytest.approx(1.0, abs=1e-12)
    y = _img(1)
    assert -1.0 <= metrics.ssim(x, y) < 0.9


@pytest.mark.parametrize("strip_rows", [None, 1, 5, 16, 100])
def test_ssim_matches_brute_force_with_zero_padding(strip_rows):
    # 19 rows: strips of 5 leave a short last strip; 16 splits the image in two; 100 is one strip.
    x, y = _img(4, 19, 18), _img(5, 19, 18)
    ref = float(brute_ssim_same(x, y).mean())
    kw = {} if strip_rows is None else {"strip_rows": strip_rows}
    assert metrics.ssim(x, y, **kw) == pytest.approx(ref, abs=1e-12)
    # float32 renders (what the runner passes) are widened to float64 first.
    x32, y32 = x.astype(np.float32), y.astype(np.float32)
    assert metrics.ssim(x32, y32, **kw) == pytest.approx(float(brute_ssim_same(x32, y32).mean()), abs=1e-12)


def test_ssim_large_image_matches_skimage_interior():
    # Many strips (default 32 rows) on a larger view: away from the 5-pixel border the zero-padded map is
    # skimage's map, so the mean over whole-image minus border-strip contributions must agree.
    x = _img(8, 100, 90)
    y = np.clip(x + np.random.default_rng(9).normal(0, 0.05, x.shape), 0, 1)
    ref = structural_similarity(x, y, data_range=1.0, gaussian_weights=True, sigma=1.5,
                                use_sample_covariance=False, channel_axis=2, full=True)[1]
    ref[:5], ref[-5:], ref[:, :5], ref[:, -5:] = 0, 0, 0, 0
    ref[:5] = brute_ssim_same(x[:10], y[:10])[:5]  # borders from the brute force (small slices)
    ref[-5:] = brute_ssim_same(x[-10:], y[-10:])[-5:]
    ref[:, :5] = brute_ssim_same(x[:, :10], y[:, :10])[:, :5]
    ref[:, -5:] = brute_ssim_same(x[:, -10:], y[:, -10:])[:, -5:]
    assert metrics.ssim(x, y) == pytest.approx(float(ref.mean()), abs=1e-12)


def test_training_ssim_in_float32_is_close_to_the_reported_one():
    import torch

    import strings_bench.engine.losses as losses

    x, y = _img(6, 24, 26), _img(7, 24, 26)
    ref = float(brute_ssim_same(x, y).mean())
    t = lambda a: torch.tensor(a, dtype=torch.float32)  # noqa: E731
    assert float(losses.ssim(t(x), t(y))) == pytest.approx(ref, abs=1e-5)
    # The same images as (1, 3, H, W) batches.
    assert float(losses.ssim(t(x).permute(2, 0, 1)[None], t(y).permute(2, 0, 1)[None])) == pytest.approx(ref, abs=1e-5)


def test_ssim_bad_strip_rows_is_clear():
    with pytest.raises(StringsBenchError, match="strip_rows"):
        metrics.ssim(np.zeros((4, 4, 3)), np.zeros((4, 4, 3)), strip_rows=0)


def test_shape_mismatch_is_clear():
    with pytest.raises(StringsBenchError, match="ground truth"):
        metrics.psnr(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))


def test_lpips_nan_without_weights(monkeypatch, tmp_path):
    import strings_bench.eval.lpips_net as lpips_net

    monkeypatch.setattr(lpips_net, "_shared", {})
    monkeypatch.setenv("STRINGS_BENCH_LPIPS_VGG", str(tmp_path / "missing.ckpt"))
    monkeypatch.setenv("STRINGS_BENCH_LPIPS_LIN", str(tmp_path / "missing.pth"))
    assert not lpips_net.available()
    assert math.isnan(metrics.lpips(np.zeros((32, 32, 3)), np.ones((32, 32, 3))))
