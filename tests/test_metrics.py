"""Image metrics against independent computations: analytic PSNR, skimage SSIM, brute-force SSIM."""

import math

import numpy as np
import pytest
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


def test_ssim_interior_matches_skimage():
    x, y = _img(2), np.clip(_img(2) + np.random.default_rng(3).normal(0, 0.05, (40, 48, 3)), 0, 1)
    ours = metrics.ssim_map(x, y)
    for c in range(3):
        _, ref = structural_similarity(x[..., c], y[..., c], data_range=1.0, gaussian_weights=True, sigma=1.5,
                                       use_sample_covariance=False, full=True)
        # Borders differ by padding convention (zero vs reflect); the interior is the same formula.
        np.testing.assert_allclose(ours[5:-5, 5:-5, c], ref[5:-5, 5:-5], atol=1e-10)


def test_ssim_matches_brute_force_with_zero_padding():
    x, y = _img(4, 16, 18), _img(5, 16, 18)
    g = metrics.gaussian_window_1d()
    win = np.outer(g, g)
    h, w = x.shape[:2]
    ref = np.zeros((h, w, 3))
    for c in range(3):
        px, py = np.pad(x[..., c], 5), np.pad(y[..., c], 5)
        for i in range(h):
            for j in range(w):
                a, b = px[i:i + 11, j:j + 11], py[i:i + 11, j:j + 11]
                mx, my = (win * a).sum(), (win * b).sum()
                vx = (win * a * a).sum() - mx**2
                vy = (win * b * b).sum() - my**2
                cxy = (win * a * b).sum() - mx * my
                ref[i, j, c] = ((2 * mx * my + 1e-4) * (2 * cxy + 9e-4)) / ((mx**2 + my**2 + 1e-4) * (vx + vy + 9e-4))
    np.testing.assert_allclose(metrics.ssim_map(x, y), ref, atol=1e-12)


def test_ssim_matches_engine_loss():
    import torch

    import strings_bench.engine.losses as losses

    x, y = _img(6), _img(7)
    t = lambda a: torch.tensor(a, dtype=torch.float32)  # noqa: E731
    assert float(losses.ssim(t(x), t(y))) == pytest.approx(metrics.ssim(x, y), abs=1e-4)
    # The same images as (1, 3, H, W) batches.
    assert float(losses.ssim(t(x).permute(2, 0, 1)[None], t(y).permute(2, 0, 1)[None])) == pytest.approx(
        metrics.ssim(x, y), abs=1e-4)


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
