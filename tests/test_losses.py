"""L1 / SSIM against independent references: skimage's SSIM, a float64 NumPy brute force of the
zero-padded ('same') convention, and autograd gradcheck."""

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from strings_bench.engine.losses import gs_loss, l1_loss, masked_l1, ssim, ssim_map


def _rand(shape, seed):
    return np.random.default_rng(seed).random(shape)


@pytest.mark.parametrize("shape", [(40, 52, 3), (23, 17, 1)])
def test_ssim_valid_matches_skimage(shape):
    a, b = _rand(shape, 1), _rand(shape, 2)
    b = 0.6 * a + 0.4 * b  # correlated, so SSIM is far from 0
    ref = structural_similarity(a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
                                data_range=1.0, channel_axis=2)
    ours = float(ssim(torch.tensor(a), torch.tensor(b), padding="valid"))
    assert abs(ours - ref) < 1e-6, (ours, ref)
    ours32 = float(ssim(torch.tensor(a, dtype=torch.float32), torch.tensor(b, dtype=torch.float32), padding="valid"))
    assert abs(ours32 - ref) < 1e-4


def _brute_same(a, b):
    """Zero-padded 11x11 Gaussian-window SSIM map in float64 loops (the 3DGS training convention)."""
    x = np.arange(11) - 5
    g = np.exp(-x ** 2 / (2 * 1.5 ** 2))
    w = np.outer(g, g) / np.outer(g, g).sum()
    H, W, C = a.shape
    pa = np.pad(a, ((5, 5), (5, 5), (0, 0)))
    pb = np.pad(b, ((5, 5), (5, 5), (0, 0)))
    out = np.zeros_like(a)
    for i in range(H):
        for j in range(W):
            wa, wb = pa[i:i + 11, j:j + 11], pb[i:i + 11, j:j + 11]
            for c in range(C):
                mx, my = (w * wa[..., c]).sum(), (w * wb[..., c]).sum()
                sxx = (w * wa[..., c] ** 2).sum() - mx ** 2
                syy = (w * wb[..., c] ** 2).sum() - my ** 2
                sxy = (w * wa[..., c] * wb[..., c]).sum() - mx * my
                out[i, j, c] = ((2 * mx * my + 1e-4) * (2 * sxy + 9e-4)) / ((mx ** 2 + my ** 2 + 1e-4) * (sxx + syy + 9e-4))
    return out


def test_ssim_same_padding_matches_brute_force():
    a, b = _rand((14, 19, 3), 3), _rand((14, 19, 3), 4)
    ours = ssim_map(torch.tensor(a), torch.tensor(b), padding="same")[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(ours, _brute_same(a, b), atol=1e-10)


def test_ssim_identical_is_one_and_gradcheck():
    a = torch.tensor(_rand((12, 13, 2), 5))
    assert float(ssim(a, a)) == pytest.approx(1.0, abs=1e-12)
    x = torch.tensor(_rand((9, 8, 2), 6), requires_grad=True)
    y = torch.tensor(_rand((9, 8, 2), 7))
    assert torch.autograd.gradcheck(lambda t: ssim(t, y), (x,), eps=1e-6, atol=1e-7)
    x2 = torch.tensor(_rand((13, 12, 1), 8), requires_grad=True)
    y2 = torch.tensor(_rand((13, 12, 1), 11))
    assert torch.autograd.gradcheck(lambda t: ssim(t, y2, padding="valid"), (x2,), eps=1e-6, atol=1e-7)


def test_l1_and_combined_loss():
    a, b = torch.tensor(_rand((6, 7, 3), 9)), torch.tensor(_rand((6, 7, 3), 10))
    assert float(l1_loss(a, b)) == pytest.approx(np.abs(a.numpy() - b.numpy()).mean())
    expected = 0.8 * float(l1_loss(a, b)) + 0.2 * (1 - float(ssim(a, b)))
    assert float(gs_loss(a, b)) == pytest.approx(expected)
    mask = torch.zeros(6, 7, dtype=torch.bool)
    mask[2:4, 1:5] = True
    ref = (np.abs(a.numpy() - b.numpy()) * mask.numpy()[..., None]).mean()
    assert float(masked_l1(a, b, mask)) == pytest.approx(ref)


def test_ssim_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="different shapes"):
        ssim(torch.zeros(5, 5, 3), torch.zeros(5, 6, 3))
