"""L1 / SSIM / PSNR against independent references: skimage's SSIM, a float64 brute force of the
zero-padded ('same') convention (tests/_ssim_reference.py), hand values, and autograd gradcheck.
These functions are also the evaluation's metrics (strings_bench.eval.metrics calls them)."""

import math

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from _ssim_reference import brute_ssim_same
from strings_bench.engine.losses import gs_loss, l1_loss, masked_l1, psnr, ssim, ssim_map


def _rand(shape, seed):
    return np.random.default_rng(seed).random(shape)


@pytest.mark.parametrize("shape", [(40, 52, 3), (23, 17, 1)])
def test_ssim_valid_matches_skimage(shape):
    a, b = _rand(shape, 1), _rand(shape, 2)
    b = 0.6 * a + 0.4 * b  # correlated, so SSIM is far from 0
    ref = structural_similarity(a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
                                data_range=1.0, channel_axis=2)
    ours = float(ssim(torch.tensor(a), torch.tensor(b), padding="valid"))
    assert abs(ours - ref) < 1e-12, (ours, ref)
    ours32 = float(ssim(torch.tensor(a, dtype=torch.float32), torch.tensor(b, dtype=torch.float32), padding="valid"))
    assert abs(ours32 - ref) < 1e-4


def test_ssim_same_padding_matches_brute_force():
    a, b = _rand((14, 19, 3), 3), _rand((14, 19, 3), 4)
    ours = ssim_map(torch.tensor(a), torch.tensor(b), padding="same")[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(ours, brute_ssim_same(a, b), atol=1e-10)


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


def test_psnr_hand_values():
    gt = torch.full((10, 12, 3), 0.5, dtype=torch.float64)
    assert psnr(gt + 0.1, gt) == pytest.approx(20.0, abs=1e-9)  # MSE 0.01
    one_off = gt.clone()
    one_off[0, 0, 0] += 1.0  # MSE 1/360
    assert psnr(one_off, gt) == pytest.approx(10 * math.log10(360), abs=1e-9)
    assert psnr(gt, gt) == math.inf
    assert psnr(gt.float() + 0.1, gt.float()) == pytest.approx(20.0, abs=1e-4)  # float32, as in training
