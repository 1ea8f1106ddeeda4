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


def _fused_and_reference(a, b, lam=0.2):
    """The numba CPU loss (float32) and its gradient, and the float64 reference: the brute-force SSIM map
    of tests/_ssim_reference.py for the value, torch's float64 autograd of the same formula for the
    gradient."""
    from strings_bench.engine.losses import fused_cpu_loss_applies

    x = torch.tensor(a, dtype=torch.float32, requires_grad=True)
    y = torch.tensor(b, dtype=torch.float32)
    assert fused_cpu_loss_applies(x, y)
    loss = gs_loss(x, y, lam)
    loss.backward()
    ref_value = (1 - lam) * np.abs(a - b).mean() + lam * (1 - brute_ssim_same(a, b).mean())
    x64 = torch.tensor(a, dtype=torch.float64, requires_grad=True)
    ((1 - lam) * (x64 - torch.tensor(b)).abs().mean() + lam * (1 - ssim(x64, torch.tensor(b)))).backward()
    return float(loss.detach()), x.grad.double(), ref_value, x64.grad


@pytest.mark.parametrize("shape,lam", [((14, 19, 3), 0.2), ((23, 9, 1), 0.2), ((16, 16, 3), 1.0), ((7, 30, 3), 0.0)])
def test_fused_cpu_loss_matches_float64_references(shape, lam):
    a, b = _rand(shape, 21), _rand(shape, 22)
    b = np.clip(0.7 * a + 0.3 * b, 0, 1)
    value, grad, ref_value, ref_grad = _fused_and_reference(a, b, lam)
    assert value == pytest.approx(ref_value, abs=2e-6)
    assert float((grad - ref_grad).norm() / ref_grad.norm()) < 1e-4


def test_fused_cpu_loss_at_the_extremes():
    # identical images: SSIM 1, L1 0; |x - y|'s gradient is 0 at 0 (torch's sign), SSIM's is 0 at its maximum
    a = _rand((12, 13, 3), 23)
    value, grad, ref_value, ref_grad = _fused_and_reference(a, a.copy())
    assert value == pytest.approx(0.0, abs=1e-6) and ref_value == pytest.approx(0.0, abs=1e-12)
    assert float(grad.abs().max()) < 1e-6 and float(ref_grad.abs().max()) < 1e-9
    # flat black against flat white (only the constants C1, C2 keep SSIM finite), and a 1-pixel image
    for a, b in ((np.zeros((10, 11, 3)), np.ones((10, 11, 3))), (_rand((1, 1, 3), 24), _rand((1, 1, 3), 25))):
        value, grad, ref_value, ref_grad = _fused_and_reference(a, b)
        assert np.isfinite(value) and value == pytest.approx(ref_value, abs=2e-6)
        assert torch.allclose(grad, ref_grad, atol=1e-6)


def test_fused_cpu_loss_is_the_same_at_any_thread_count():
    import numba

    from strings_bench.engine.loss_kernels import gs_loss_backward, gs_loss_forward

    a = _rand((40, 56, 3), 26).astype(np.float32)
    b = _rand((40, 56, 3), 27).astype(np.float32)
    results = []
    for n in (1, numba.config.NUMBA_NUM_THREADS):
        numba.set_num_threads(n)
        loss, _, partial = gs_loss_forward(a, b, 0.2, True)
        results.append((loss, gs_loss_backward(a, b, partial, 0.2, 1.0)))
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    assert results[0][0] == results[1][0]
    assert np.array_equal(results[0][1], results[1][1])
